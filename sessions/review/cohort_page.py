"""A cohort as one self-contained HTML page: the sessions, the learning curves, each task's skill metrics.

The page fits a 1400 px window and a 400 px phone: the sessions table keeps
the columns that say which session it was (the numbers graded by are in the
task's tables), headers are words that wrap, the skill metrics are split per
task into a forces table and a time-and-motion table of nine columns each,
and every table sits in a ``fit`` box that scrolls sideways on its own when a
narrow window cannot hold it (the page itself never does). The tables list
the CSV's rows in its order (task, trainee, session).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from hapticlab.sessions.review.cohort import NO_TRAINEE, order, trainee_of
from hapticlab.sessions.review.learning import NO_TASK, learning_pngs
from hapticlab.sessions.review.page import _e, _img, document, fit, table
from hapticlab.sessions.review.skill_names import KEYS, header

SESSION_COLUMNS = (
    ("trainee", "trainee"),
    ("task", "task"),
    ("session", "session"),
    ("date", "date"),
    ("duration_s", "duration (s)"),
    ("contacts", "contacts"),
    ("parameters_known_s", "parameters known (s)"),
    ("issues", "to look at"),
    ("recording", "recording"),
)
"""The sessions table: (column, header words); ``issues`` gathers faults, lost samples and a missing end, and
an ``estimator`` column is added when the cohort's sessions were not all driven by the same one."""
FORCES: tuple[str, ...] = ("peak_force_N", "force_time_integral_Ns", "mean_force_rate_N_s", "max_force_rate_N_s")
FORCES += ("excess_force_events", "excess_force_time_s", "contact_time_s")
MOTION = tuple(k for k in KEYS if k not in FORCES)
"""The two halves of a task's skill metrics (seven columns each, beside trainee and session)."""


def cell(value: Any) -> str:
    """A value as a table cell: – when unknown, whole numbers as such, 2 decimals (1 from 100, 0 from 1000)."""
    if value is None or value == "" or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{2 if abs(value) < 100 else 1 if abs(value) < 1000 else 0}f}"
    return _e(value)


def issues(row: dict[str, Any]) -> str:
    """What to look at in a session, in words: its faults, lost samples, a missing end ("none")."""
    said = [
        f"{row[k]} {words}" for k, words in (("faults", "fault(s)"), ("lost_samples", "lost sample(s)")) if row.get(k)
    ]
    if row.get("complete") is False:
        said.append("no end (recovered or cut short)")
    return ", ".join(said) or "none"


def _session_cell(row: dict[str, Any], column: str) -> str:
    if column == "trainee":
        return _e(trainee_of(row))
    if column == "task":
        return _e(row.get("task") or NO_TASK)
    if column == "date":
        day, _, time = str(row.get("date") or "–")[:16].partition("T")  # to the minute; a line break between
        return " ".join(f"<span class=nowrap>{_e(part)}</span>" for part in (day, time) if part)
    if column == "issues":
        return _e(issues(row))
    if column == "recording":  # a path breaks after its slashes and underscores, not inside a word
        return _e(row.get("recording") or "").replace("/", "/<wbr>").replace("_", "_<wbr>")
    return cell(row.get(column))


def cohort_page(rows: Sequence[dict[str, Any]], title: str, refused: Sequence[tuple[str, str]] = ()) -> str:
    """The cohort (rows of :func:`~.cohort.rows_of`) as a self-contained HTML page.

    The sessions table (id ``cohort``), the files not reviewed (``refused``), the learning curves, then per
    task its forces (``task-<n>-forces``) and time-and-motion (``task-<n>-motion``) tables.
    """
    rows = sorted(rows, key=order)
    trainees = {r["trainee"] for r in rows if r.get("trainee")}
    unnamed = sum(1 for r in rows if not r.get("trainee"))
    tasks: list[str] = []
    for r in rows:
        if (r.get("task") or "") not in tasks:
            tasks.append(r.get("task") or "")
    count = f"{len(rows)} session(s), {len(trainees)} trainee(s), {len(tasks)} task(s)"
    if unnamed:
        count += f"; {unnamed} session(s) without a trainee, shown as {NO_TRAINEE} and kept out of the curves"
    estimators = sorted({str(r["estimator"]) for r in rows if r.get("estimator")})
    if len(estimators) == 1:
        count += f"; estimator {estimators[0]}"
    columns = list(SESSION_COLUMNS)
    if len(estimators) > 1:
        columns.insert(-2, ("estimator", "estimator"))
    body = [
        f"<h1>{_e(title)}</h1>",
        f"<p>{_e(count)}.</p>",
        "<h2>Sessions</h2>",
        fit(
            table(
                [words for _, words in columns],
                [[_session_cell(r, c) for c, _ in columns] for r in rows],
                id="cohort",
                text_columns=2,
            )
        ),
    ]
    if refused:
        body.append(
            "<h2>Not reviewed</h2>"
            + fit(table(("recording", "why"), [(_e(p), _e(w)) for p, w in refused], id="refused", text_columns=2))
        )
    pngs = learning_pngs(rows)
    if pngs:
        body.append(
            "<h2>Learning curves</h2><p>Each trainee's sessions of a task, against the cohort's median and "
            "25–75 % band at that session (over the trainees who had it, two at least).</p>"
        )
        body.extend(_img(png, "learning curves") for png in pngs)
    for n, task in enumerate(tasks, start=1):
        of_task = [r for r in rows if (r.get("task") or "") == task]
        body.append(f"<h2>Skill metrics: {_e(task or NO_TASK)}</h2>")
        for part, keys in (("forces", FORCES), ("motion", MOTION)):
            body.append(
                fit(
                    table(
                        ["trainee", "session", *(_e(header(k)) for k in keys)],
                        [[_e(trainee_of(r)), str(r["session"]), *(cell(r.get(k)) for k in keys)] for r in of_task],
                        id=f"task-{n}-{part}",
                    )
                )
            )
    return document(title, "".join(body))
