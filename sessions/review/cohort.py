"""A cohort: every session in a folder reviewed (in parallel, on the Dask engine), one row each.

:func:`review_folder` runs :func:`~.summary.review` (without plots) over each
recording on ``offline.folders.map_recordings`` (local worker processes by
default, an existing Dask cluster with ``scheduler``) and keeps each
session's row (:meth:`~.summary.SessionReview.row`): trainee, task, date,
duration, contacts, peak force, time over the limit, estimator, convergence.
The rows become a CSV (:func:`csv_text`), an HTML page with each trainee's
progress plotted across their sessions (:func:`cohort_page`), or the
terminal's table.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

from hapticlab.sessions.offline.folders import FolderRun, map_recordings, recordings_in
from hapticlab.sessions.review.summary import review

COLUMNS = (
    "recording",
    "trainee",
    "task",
    "date",
    "duration_s",
    "contacts",
    "peak_force_N",
    "over_limit_s",
    "contact_s",
    "force_limit_N",
    "estimator",
    "converged_s",
    "lost_samples",
    "faults",
    "complete",
)
"""The cohort's columns (CSV header), in order."""


def review_row(path: Path, force_limit: float | None = None) -> dict[str, Any]:
    """One session's cohort row (the task each worker runs)."""
    return review(path, force_limit=force_limit, plots=False).row()


def review_folder(
    folder: str | os.PathLike[str],
    force_limit: float | None = None,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> FolderRun:
    """Review every recording under ``folder``; a :class:`FolderRun` whose values are the rows.

    The rows' ``recording`` is the path relative to ``folder``. A file that is
    not a session recording is an outcome with its one-line error, not the end of the job.
    """
    if force_limit is not None and not force_limit > 0:
        raise ValueError(f"--force-limit: must be > 0 N, got {force_limit!r}")
    folder = Path(folder)
    run = map_recordings(
        partial(review_row, force_limit=force_limit),
        recordings_in(folder),
        scheduler=scheduler,
        workers=workers,
        progress=progress,
        description="reviewing",
    )
    for outcome in run.outcomes:
        if outcome.value is not None:
            outcome.value["recording"] = str(outcome.path.relative_to(folder))
    return run


def rows_of(run: FolderRun) -> list[dict[str, Any]]:
    """The rows of the sessions that were reviewed, in date order (then path)."""
    rows = [o.value for o in run.outcomes if o.value is not None]
    return sorted(rows, key=lambda r: (r["date"], r["recording"]))


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as CSV (header :data:`COLUMNS`; an unknown value empty)."""
    out = io.StringIO()
    writer = csv.DictWriter(out, COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    return out.getvalue()


def progress_png(rows: Sequence[dict[str, Any]]) -> bytes:
    """Each trainee's sessions in date order: peak contact force and time over the limit, one line per trainee."""
    import matplotlib

    from hapticlab.sessions.review.plots import figure_png

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    by_trainee: dict[str, list[dict[str, Any]]] = {}
    for row in rows:
        by_trainee.setdefault(row["trainee"] or "(unnamed)", []).append(row)
    for trainee, sessions in sorted(by_trainee.items()):
        n = range(1, len(sessions) + 1)
        axes[0].plot(
            n,
            [s["peak_force_N"] if s["peak_force_N"] is not None else float("nan") for s in sessions],
            marker="o",
            label=trainee,
        )
        axes[1].plot(n, [s["over_limit_s"] for s in sessions], marker="o", label=trainee)
    limits = sorted({r["force_limit_N"] for r in rows})
    if len(limits) == 1:
        axes[0].axhline(limits[0], color="tab:red", linestyle="--", linewidth=1.0, label=f"limit {limits[0]:g} N")
    axes[0].set_ylabel("peak contact force [N]")
    axes[1].set_ylabel("time over the limit [s]")
    axes[1].set_xlabel("the trainee's session (in date order)")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=4)
    fig.suptitle("Progress per trainee")
    return figure_png(plt, fig)


def cohort_page(rows: Sequence[dict[str, Any]], title: str, refused: Sequence[tuple[str, str]] = ()) -> str:
    """The cohort as a self-contained HTML page: the table, the refused files, the progress plot."""
    from hapticlab.sessions.review.page import _e, _img, document, table

    shown = [c for c in COLUMNS if c != "complete"]
    body = [
        f"<h1>{_e(title)}</h1>",
        f"<p>{len(rows)} session(s), {len({r['trainee'] for r in rows})} trainee(s).</p>",
        table(
            shown, [[_e("" if r.get(c) is None else r[c]) for c in shown] for r in rows], id="cohort", text_columns=4
        ),
    ]
    if refused:
        body.append(
            "<h2>Not reviewed</h2>"
            + table(("recording", "why"), [(_e(p), _e(w)) for p, w in refused], id="refused", text_columns=2)
        )
    if rows:
        body.append(f"<h2>Progress per trainee</h2>{_img(progress_png(rows), 'progress per trainee')}")
    return document(title, "".join(body))
