"""A cohort: every session in a folder reviewed (in parallel, on the Dask engine), one row each.

:func:`review_folder` runs :func:`~.summary.review` (without plots) over each
recording on ``offline.folders.map_recordings`` (local worker processes by
default, an existing Dask cluster with ``scheduler``) and keeps each
session's row (:meth:`~.summary.SessionReview.row`). :func:`rows_of` numbers
each trainee's sessions of a task (``session``: 1, 2, ... in date order) and
orders the rows by task, trainee, session: the order of the CSV
(:func:`csv_text`), the Parquet file (:func:`write_parquet`) and the HTML page's
tables (``cohort_page.py``). A session without a trainee is kept apart: not a
trainee, not a learning curve, numbered among the task's other unnamed sessions.
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
from hapticlab.sessions.review.skill_names import KEYS
from hapticlab.sessions.review.summary import review

NO_TRAINEE = "(no trainee)"
"""How the page names the sessions recorded without a trainee (the CSV leaves ``trainee`` empty)."""

COLUMNS = (
    "recording",
    "trainee",
    "task",
    "session",
    "date",
    *KEYS,
    "duration_s",
    "contacts",
    "force_limit_N",
    "estimator",
    "parameters_known_s",
    "lost_samples",
    "faults",
    "complete",
)
"""The cohort's columns (CSV header, Parquet schema), in order; each number's unit ends its name
(``_s``, ``_N``, ...), except ``task_score`` (%), ``sparc`` (no unit) and the counts."""

TEXT = frozenset({"recording", "trainee", "task", "date", "estimator"})
INTEGER = frozenset({"session", "contacts", "lost_samples", "faults", "excess_force_events"})
"""Columns of whole numbers (Parquet int64); ``complete`` is a bool; every other number a float64."""


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
    """The rows of the sessions that were reviewed, numbered and ordered (:func:`numbered`)."""
    return numbered([o.value for o in run.outcomes if o.value is not None])


def numbered(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rows (copies) with ``session``, ordered by task, trainee (the unnamed last), session.

    ``session`` is the trainee's n-th session of that task (1-based, by date, then path): a learning
    curve's x. Numbered per task because a curve compares attempts at the same task; a trainee's
    sessions of another task would leave gaps in it. The unnamed sessions of a task are numbered
    among themselves (so the column stays an integer), and drawn apart.
    """
    by_date = sorted(rows, key=lambda r: (r.get("date") or "", r.get("recording") or ""))
    counts: dict[tuple[str, str], int] = {}
    out = []
    for row in by_date:
        key = (row.get("task") or "", row.get("trainee") or "")
        counts[key] = counts.get(key, 0) + 1
        out.append({**row, "session": counts[key]})
    return sorted(out, key=order)


def order(row: dict[str, Any]) -> tuple:
    """The cohort's row order: task (the unnamed task last), trainee (the unnamed last), session."""
    task, trainee = row.get("task") or "", row.get("trainee") or ""
    return (not task, task, not trainee, trainee, row["session"], row.get("recording") or "")


def trainee_of(row: dict[str, Any]) -> str:
    """The trainee's name, or :data:`NO_TRAINEE`."""
    return row.get("trainee") or NO_TRAINEE


def csv_text(rows: Sequence[dict[str, Any]]) -> str:
    """The rows as CSV (header :data:`COLUMNS`; an unknown value empty), in the order given."""
    out = io.StringIO()
    writer = csv.DictWriter(out, COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in COLUMNS})
    return out.getvalue()


PARQUET_MISSING = "--parquet: needs pyarrow; pip install 'hapticlab[parquet]'"


def parquet_table(rows: Sequence[dict[str, Any]]):
    """The rows as a ``pyarrow.Table``: the CSV's columns in its order, typed (text, int64, float64, bool; an
    unknown value null). Raises ImportError without pyarrow (an optional extra: ``hapticlab[parquet]``)."""
    import pyarrow as pa

    def kind(column: str):
        if column in TEXT:
            return pa.string()
        if column in INTEGER:
            return pa.int64()
        return pa.bool_() if column == "complete" else pa.float64()

    return pa.table(
        {c: pa.array([row.get(c) for row in rows], type=kind(c)) for c in COLUMNS},
        schema=pa.schema([(c, kind(c)) for c in COLUMNS]),
    )


def write_parquet(path: str | os.PathLike[str], rows: Sequence[dict[str, Any]], force: bool = False) -> Path:
    """Write :func:`parquet_table` to ``path`` (through ``atomic_output``: refused if it exists, unless force)."""
    import pyarrow.parquet as pq

    from hapticlab.sessions.output import atomic_output

    table = parquet_table(rows)
    with atomic_output(path, force, label="--parquet") as tmp:
        pq.write_table(table, str(tmp))
    return Path(path)
