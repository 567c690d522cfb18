"""``hapticlab compensate``, ``replay`` and ``recover``: the offline tools over one recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from hapticlab.sessions.cli.render import err, fmt, wide_console


def add_force(parser: argparse.ArgumentParser) -> None:
    """``--force``, for every command that writes files: without it an existing output is refused."""
    parser.add_argument(
        "--force",
        action="store_true",
        help="overwrite existing output files (every output is written to a temporary file "
        "and renamed into place, so a failure never leaves half a file)",
    )


def cmd_compensate(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from hapticlab.sessions.offline.compensate import compensate

    with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
        task = progress.add_task(f"compensating {Path(args.input).name}", total=None)
        result = compensate(
            args.input,
            args.output,
            estimator_name=args.estimator,
            overrides=args.set or [],
            params_out=args.params_out,
            force=args.force,
            keep_estimates=False,
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )
    for note in result.notes:
        err.print(f"note: {note}")

    def vector(values, unit):
        if all(v != v for v in values):  # NaN: that stage never converged
            return "n/a (not converged)"
        return "[" + ", ".join(f"{x:.4g}" for x in values) + f"] {unit}"

    err.print(
        f"{Path(args.input).name}: {result.rows} rows → {args.output} ({args.estimator}); "
        f"force converged at sample {result.first_converged_force}, torque at "
        f"{result.first_converged_torque}"
    )
    err.print(
        f"RMS contact wrench on no-contact rows after convergence: force "
        f"{vector(result.rms_force_S, 'N')}, torque {vector(result.rms_torque_S, 'N·m')}"
    )
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from rich.table import Table

    from hapticlab.sessions.offline.replay import replay

    if Path(args.recording).is_dir():
        return replay_folder_table(args)
    with err.status(f"replaying {Path(args.recording).name} through {args.estimator}"):
        result = replay(args.recording, args.estimator, args.output, overrides=args.set or [], force=args.force)
    t = Table(title=f"{Path(args.recording).name}: {result['rows']} samples; no-contact samples after convergence")
    for col in ("estimator topic", "force conv.", "RMS fx, fy, fz (N)", "Max AE fx, fy, fz (N)", "contact agreement"):
        t.add_column(col, justify="right")
    for topic, r in result["comparison"].items():
        rms = ", ".join(fmt(v) for v in r["rms_force_S"]) if r.get("rms_force_S") else "–"
        mx = ", ".join(fmt(v) for v in r["max_ae_force_S"]) if r.get("max_ae_force_S") else "–"
        agree = f"{r['contact_agreement_pct']:.1f} %" if "contact_agreement_pct" in r else "–"
        name = f"{topic} (new)" if topic == result["topic"] else topic
        t.add_row(name, str(r["converged_force_at"]), rms, mx, agree)
    wide_console(120).print(t)
    if args.output:
        err.print(f"wrote {args.output} (the original topics and {result['topic']})")
    return 0


def replay_folder_table(args: argparse.Namespace) -> int:
    """``hapticlab replay DIR/``: every recording in the folder, one row each."""
    import math

    from hapticlab.core.errors import UserError
    from hapticlab.sessions.offline.replay import replay_folder

    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers: at least 1, got {args.workers}")
    run = replay_folder(
        args.recording,
        args.estimator,
        args.output,
        overrides=args.set or [],
        force=args.force,
        scheduler=args.scheduler,
        workers=args.workers,
        progress=err.is_terminal,
    )

    def norm(entry):
        values = entry.get("rms_force_S") if entry else None
        return fmt(math.sqrt(sum(v * v for v in values))) if values else "–"

    def row(result) -> list[str]:
        new = result["comparison"][result["topic"]]
        recorded = "; ".join(
            f"{topic.removeprefix('/estimator/')} {e['converged_force_at']} / {norm(e)}"
            for topic, e in result["comparison"].items()
            if topic != result["topic"]
        )
        return [str(result["rows"]), recorded or "–", f"{new['converged_force_at']} / {norm(new)}"]

    status = print_folder_run(
        run,
        args.recording,
        f"{args.recording}: {len(run.outcomes)} recordings through {args.estimator} "
        f"(|RMS| of the contact force on no-contact samples after convergence, N)",
        ("samples", "recorded estimators: conv. / |RMS|", "new: conv. / |RMS|"),
        row,
    )
    written = sum(not outcome.error for outcome in run.outcomes)
    if args.output and written:  # (every file refused: nothing was written, the table says why)
        err.print(f"wrote {written} replayed recording(s) under {args.output}")
    return status


def print_folder_run(run, folder, title: str, columns: tuple[str, ...], row) -> int:
    """A folder job's table (one row per recording, ``row(value)`` its cells; a refused file its error in
    the last column) and its workers' figures; exit status 2 when a file was refused, else 0."""
    from rich.table import Table

    t = Table(title=title)
    for col in ("recording", *columns):
        t.add_column(col, justify="right")
    failed = 0
    for outcome in run.outcomes:
        name = str(outcome.path.relative_to(folder))
        if outcome.error:
            failed += 1
            t.add_row(name, *["–"] * (len(columns) - 1), f"[red]{outcome.error}[/]")
        else:
            t.add_row(name, *row(outcome.value))
    wide_console(140).print(t)
    peak = max(run.peak_rss_mb.values(), default=0.0)
    err.print(
        f"{len(run.outcomes)} recordings, {run.workers} worker(s), {run.wall_s:.1f} s, "
        f"peak memory per worker {peak:.0f} MB" + (f"; {failed} refused" if failed else "")
    )
    return 2 if failed else 0


def add_folder_options(parser: argparse.ArgumentParser) -> None:
    """``--scheduler`` and ``--workers``, for every command that takes a folder of recordings."""
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on an existing Dask cluster (tcp://HOST:PORT); default: local worker processes",
    )
    parser.add_argument("--workers", type=int, default=None, help="local worker processes (default: one per core)")


def cmd_recover(args: argparse.Namespace) -> int:
    from hapticlab.sessions.recording import recover

    counts = recover(args.broken, args.output, force=args.force)
    err.print(f"recovered {counts.get('messages', 0)} messages into {args.output}")
    for topic, n in sorted(counts.get("topics", {}).items()):
        err.print(f"  {topic}: {n}")
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser("compensate", help="run an estimator offline over a CSV or MCAP recording")
    p.add_argument("input", help="CSV (import contract), .parquet with its columns, or .mcap recording")
    p.add_argument("-o", "--output", required=True, help="output CSV (or .parquet) of the contact wrench per row")
    p.add_argument("--estimator", default="rls", help="estimator name (default: rls)")
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="estimator option, e.g. --set estimator.force_threshold=2"
    )
    p.add_argument("--params-out", default=None, help="write the final parameters as JSON")
    add_force(p)
    p.set_defaults(func=cmd_compensate)

    p = sub.add_parser("replay", help="re-run a recording (or a folder of them) through another estimator and compare")
    p.add_argument("recording", help="a session's .mcap, or a folder: every .mcap under it, in parallel")
    p.add_argument("--estimator", required=True, help="estimator name, e.g. batch")
    p.add_argument(
        "-o",
        "--output",
        default=None,
        help="write a new .mcap with the replayed estimator added (a folder, for a folder)",
    )
    add_folder_options(p)
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="estimator option, e.g. --set estimator.force_threshold=0.5"
    )
    add_force(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("recover", help="salvage a recording whose writer died")
    p.add_argument("broken", help="the damaged .mcap")
    p.add_argument("-o", "--output", required=True, help="where to write the recovered .mcap")
    add_force(p)
    p.set_defaults(func=cmd_recover)
