"""``hapticlab review``: one session's report (terminal, HTML, PNG plots), or a folder's cohort table."""

from __future__ import annotations

import argparse
import json
import math
import statistics
from pathlib import Path

from hapticlab.core.errors import UserError
from hapticlab.sessions.cli.offline import add_folder_options, add_force, print_folder_run
from hapticlab.sessions.cli.render import err, fmt, wide_console
from hapticlab.sessions.output import check_output, check_plots_folder, write_text
from hapticlab.sessions.review.skill_names import KEYS


def print_review(r) -> None:
    """A session's review as the terminal's tables."""
    from rich.table import Table

    from hapticlab.sessions.review.page import ERROR_HEADER, error_rows, summary_rows
    from hapticlab.sessions.review.summary import faults

    console = wide_console(120)
    who = " · ".join(x for x in (r.trainee and f"trainee [bold]{r.trainee}[/]", r.task and f"task {r.task}") if x)
    console.print(
        f"[bold]{r.name or r.path.name}[/] ({r.path.name}) · {who or 'no trainee recorded'} · "
        f"{r.date or 'no date'} · {r.duration_s:.1f} s · estimator {r.estimator}"
        + ("" if r.complete else " · [yellow]no summary: recovered or cut short[/]")
    )
    if r.notes:
        console.print(f"notes: {r.notes}")
    t = Table(title="summary", show_header=False)
    t.add_column("measure")
    t.add_column("value")
    for measure, value in summary_rows(r):
        t.add_row(measure, value)
    console.print(t)
    if r.contacts:
        t = Table(title=f"contacts (‖contact force‖ from {r.estimator})")
        for col in ("#", "start (s)", "duration (s)", "peak (N)", "mean (N)", f"over {r.force_limit_N:g} N (s)"):
            t.add_column(col, justify="right")
        for i, c in enumerate(r.contacts, start=1):
            t.add_row(
                str(i),
                fmt(c.start_s, 2),
                fmt(c.duration_s, 2),
                fmt(c.peak_N, 2),
                fmt(c.mean_N, 2),
                fmt(c.over_limit_s, 2),
            )
        console.print(t)
    t = Table(title="estimators")
    for col in ("estimator", "samples", "force converged (s)", "torque converged (s)", "converged at end"):
        t.add_column(col, justify="right")
    for e in r.estimators:
        t.add_row(
            e.name,
            str(e.samples),
            fmt(e.converged_force_s, 2),
            fmt(e.converged_torque_s, 2),
            "yes" if e.converged_at_end else "[red]no[/]",
        )
    console.print(t)
    for e in r.estimators:
        if not e.table:
            console.print(f"{e.name}: not scored (never converged, or no contact-free sample after)")
            continue
        t = Table(
            title=f"{e.name}: compensation error on {e.scored} no-contact samples after convergence "
            "(the paper's table; N, N·m)"
        )
        for col in ERROR_HEADER:
            t.add_column(col, justify="right")
        for row in error_rows(e):
            t.add_row(*row)
        console.print(t)
    shown = faults(r.events)
    if shown:
        t = Table(title="faults and fail-safes")
        for col in ("time (s)", "event", "message"):
            t.add_column(col, justify="left" if col == "message" else "right")
        for ev in shown:
            t.add_row(fmt(r.t_s(ev.t_ns), 3), ev.kind, ev.message)
        console.print(t)
    else:
        console.print("faults and fail-safes: none")


def review_session(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from hapticlab.sessions.review import review
    from hapticlab.sessions.review.plots import PLOTS, write_plots
    from hapticlab.sessions.review.report import session_page

    html = (
        check_output(args.html, args.force, label="--html", inputs=[args.input], role="recording")
        if args.html
        else None
    )
    plots = check_plots_folder(args.plots, args.force, patterns=[f"{n}.png" for n in PLOTS]) if args.plots else None
    out_json = (
        check_output(args.json, args.force, label="--json", inputs=[args.input], role="recording")
        if args.json
        else None
    )
    cohort = Path(args.cohort) if args.cohort else None
    if cohort is not None and not cohort.is_dir():
        raise UserError(f"--cohort: {args.cohort}: not a folder of recordings")
    if args.csv:
        raise UserError("--csv: a cohort's table; give a folder of recordings (hapticlab review DIR/ --csv FILE)")
    if args.parquet:
        raise UserError(
            "--parquet: a cohort's table; give a folder of recordings (hapticlab review DIR/ --parquet FILE)"
        )
    with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
        task = progress.add_task(f"reviewing {Path(args.input).name}", total=1.0)
        r = review(
            args.input,
            force_limit=args.force_limit,
            plots=bool(html or plots),
            progress=lambda done: progress.update(task, completed=done),
        )
    print_review(r)
    medians, size = None, 0
    if cohort is not None:
        rows = cohort_rows(cohort, r.task)
        size = len(rows)
        medians = {k: _median([row.get(k) for row in rows]) for k in KEYS}
    if out_json is not None:
        write_text(out_json, json.dumps(review_json(r, medians), indent=2) + "\n", args.force, label="--json")
        err.print(f"wrote {out_json}")
    if plots is not None:
        for path in write_plots(r, plots, args.force):
            err.print(f"wrote {path}")
    if html is not None:
        write_text(html, session_page(r, medians, size), args.force, label="--html")
        err.print(f"wrote {html}")
    return 0


def cohort_rows(folder: Path, task: str) -> list[dict]:
    """The rows of ``folder``'s sessions of ``task`` (reviewed here, one after the other, with a progress bar: a
    report's medians need no cluster); a file that is not a recording is left out, with its one line."""
    from rich.progress import track

    from hapticlab.sessions.offline.folders import recordings_in
    from hapticlab.sessions.review.cohort import review_row

    rows = []
    for path in track(recordings_in(folder), description="the cohort", console=err, disable=not err.is_terminal):
        try:
            row = review_row(path)
        except ValueError as exc:
            err.print(f"--cohort: left out {path.name}: {exc}")
            continue
        if row["task"] == task:
            rows.append(row)
    return rows


def _median(values) -> float | None:
    finite = [float(v) for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    return statistics.median(finite) if finite else None


def review_json(r, medians: dict | None = None) -> dict:
    """``review --json``: the cohort row's keys (the skill metrics among them, ``docs/review.md``), the task's
    outcome, the moments in words, the contacts, and the cohort's medians when asked."""
    from dataclasses import asdict

    from hapticlab.sessions.review.skill_names import METRICS
    from hapticlab.sessions.review.timeline import moments

    def plain(value):
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        if hasattr(value, "tolist"):
            return value.tolist()
        return None if isinstance(value, float) and not math.isfinite(value) else value

    row = r.row()
    row["recording"] = r.path.name
    return plain(
        {
            **row,
            "task_outcome": r.outcome,
            "task_settings": r.task_settings,
            "moments": [asdict(m) for m in moments(r)],
            "contacts_list": [asdict(c) for c in r.contacts],
            "cohort_median": medians,
            "units": {key: unit for key, _, unit in METRICS},
        }
    )


def review_cohort(args: argparse.Namespace) -> int:
    from hapticlab.sessions.review.cohort import COLUMNS, PARQUET_MISSING, csv_text, review_folder, rows_of
    from hapticlab.sessions.review.cohort_page import cohort_page

    if args.plots:
        raise UserError("--plots: one session's figures; the cohort's learning curves are in --html")
    if args.json or args.cohort:
        raise UserError("--json and --cohort: for one session (hapticlab review REC.mcap --json OUT --cohort DIR)")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers: at least 1, got {args.workers}")
    html = check_output(args.html, args.force, label="--html") if args.html else None
    out_csv = check_output(args.csv, args.force, label="--csv") if args.csv else None
    parquet = check_output(args.parquet, args.force, label="--parquet") if args.parquet else None
    if parquet is not None:
        try:
            import pyarrow.parquet  # noqa: F401  (asked before the work, not after it)
        except ImportError:
            raise UserError(PARQUET_MISSING) from None
    run = review_folder(
        args.input, args.force_limit, scheduler=args.scheduler, workers=args.workers, progress=err.is_terminal
    )
    shown = (
        "trainee",
        "task",
        "date",
        "duration_s",
        "contacts",
        "task_score",
        "peak_force_N",
        "excess_force_events",
        "estimator",
        "parameters_known_s",
    )

    def row(value) -> list[str]:
        return [
            "–"
            if value.get(c) is None or value.get(c) == ""
            else (fmt(value[c], 2) if isinstance(value[c], float) else str(value[c]))
            for c in shown
        ]

    status = print_folder_run(
        run,
        args.input,
        f"{args.input}: {len(run.outcomes)} recordings (force limit "
        + (f"{args.force_limit:g} N)" if args.force_limit is not None else "each session's task's, else 3 N)"),
        shown,
        row,
    )
    ordered = rows_of(run)  # task, trainee, session: the CSV's, the Parquet file's and the page's order
    if out_csv is not None:
        write_text(out_csv, csv_text(ordered), args.force, label="--csv")
        err.print(f"wrote {out_csv} ({len(ordered)} rows, columns {', '.join(COLUMNS)})")
    if parquet is not None:
        from hapticlab.sessions.review.cohort import write_parquet

        write_parquet(parquet, ordered, args.force)
        err.print(f"wrote {parquet} ({len(ordered)} rows, the CSV's columns)")
    if html is not None:
        refused = [(str(o.path.relative_to(args.input)), o.error) for o in run.outcomes if o.error]
        write_text(html, cohort_page(ordered, f"Cohort review: {args.input}", refused), args.force, label="--html")
        err.print(f"wrote {html}")
    return status


def cmd_review(args: argparse.Namespace) -> int:
    if args.force_limit is not None and not args.force_limit > 0:
        raise UserError(f"--force-limit: must be > 0 N, got {args.force_limit:g}")
    path = Path(args.input)
    if path.is_dir():
        return review_cohort(args)
    if not path.exists():
        raise UserError(f"{args.input}: no such file or folder")
    return review_session(args)


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``review`` to the ``hapticlab`` parser."""
    from hapticlab.sessions.review.session import DEFAULT_FORCE_LIMIT_N

    p = sub.add_parser(
        "review",
        help="review a recorded session (summary, tables, plots, HTML) or a folder of them "
        "(a cohort: one row per session, CSV, Parquet, HTML with learning curves per trainee and task)",
    )
    p.add_argument("input", help="a session's .mcap, or a folder of them (a cohort)")
    p.add_argument(
        "--html", default=None, metavar="FILE.html", help="write a self-contained page (tables and plots embedded)"
    )
    p.add_argument("--plots", default=None, metavar="DIR", help="write the session's plots as PNG into DIR")
    p.add_argument("--csv", default=None, metavar="FILE.csv", help="a cohort: write its table as CSV")
    p.add_argument(
        "--json",
        default=None,
        metavar="FILE.json",
        help="one session: write every metric of the report as JSON (keys as in the cohort CSV: docs/review.md)",
    )
    p.add_argument(
        "--cohort",
        default=None,
        metavar="DIR",
        help="one session: show the median of DIR's sessions of the same task beside each metric",
    )
    p.add_argument(
        "--parquet",
        default=None,
        metavar="FILE.parquet",
        help="a cohort: write the CSV's table as Parquet, typed (pandas, DuckDB; needs hapticlab[parquet])",
    )
    p.add_argument(
        "--force-limit",
        type=float,
        default=None,
        metavar="N",
        help=f"contact force limit the review counts time above, N (default: the session's task's, "
        f"else {DEFAULT_FORCE_LIMIT_N:g})",
    )
    add_folder_options(p)
    add_force(p)
    p.set_defaults(func=cmd_review)
