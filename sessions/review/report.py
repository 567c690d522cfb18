"""The instructor's report of one session, as one self-contained HTML page (``review REC --html``).

Built around the trainee, in the order an instructor reads it: who and which task, the outcome and score;
the force timeline with every moment said in words (``timeline.py``); the skill metrics with the cohort's
median beside each (``--cohort DIR``: the other sessions of the same task); what interrupted the session.
The engineer's part (the streams' health, the estimators, the paper's tables, every plot) is an appendix.
The page reads on a 1400 px screen and on a phone: narrow tables, images that scale, long tables that wrap.
"""

from __future__ import annotations

import math
from typing import Any

from hapticlab.sessions.review import plots
from hapticlab.sessions.review.page import ERROR_HEADER, _e, _img, _num, document, error_rows, fit, summary_rows, table
from hapticlab.sessions.review.session import SessionReview, faults
from hapticlab.sessions.review.skill_names import METRICS
from hapticlab.sessions.review.timeline import moments, timeline

REPORT_STYLE = """
.outcome { font-size: 1.1em; background: #f4f8f4; border-left: 6px solid #4a4; padding: 0.6em 0.9em; }
.outcome .score { font-size: 2em; font-weight: bold; }
.appendix { margin-top: 3em; color: #444; }
ol.moments li { margin: 0.3em 0; }
@media (max-width: 600px) {
  body { margin: 0.6em; font-size: 15px; }
  table { font-size: 0.72em; } th, td { padding: 0.2em 0.3em; }
}
"""


def objective(task: dict[str, Any]) -> str:
    """What the task asked, in words."""
    name, limit = task.get("name", ""), task.get("force_limit", 3.0)
    if name == "palpation":
        return (
            f"Find the stiffer inclusion under the tissue and mark it (button {task.get('mark_button')}), "
            f"pressing under {limit:g} N."
        )
    if name == "retraction":
        low, high = task.get("band", (0, 0))
        return f"Hold the tissue at {low:g}–{high:g} N for {task.get('hold', 0):g} s."
    if name == "tracing":
        return f"Trace the {1e3 * task.get('span', 0):.0f} mm line on the surface, staying under {limit:g} N."
    return "No task was set for this session: its metrics are shown without a score."


def outcome_words(r: SessionReview) -> str:
    """The task's outcome, in words."""
    o, name = r.outcome, r.task_settings.get("name", "")
    if name == "palpation":
        if not o.get("marks"):
            return "No mark was made."
        if o.get("mark_error_m") is None:
            return "Marked; the inclusion's place is not recorded, so the mark is not scored."
        return f"Marked {1e3 * o['mark_error_m']:.1f} mm from the inclusion's centre."
    if name == "retraction":
        return f"{o.get('time_in_band_s', 0):.1f} s in the band, of {r.task_settings.get('hold', 0):g} s asked."
    if name == "tracing":
        if o.get("path_error_m") is None:
            return "The line was not traced (no contact while following)."
        return f"{1e3 * o['path_error_m']:.1f} mm RMS from the line; {100 * o['coverage']:.0f} % of its length covered."
    return ""


def _value(key: str, value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, int) or key == "excess_force_events":
        return str(int(value))
    return _num(value, 4 if key == "path_length_m" else 2)


def session_page(r: SessionReview, medians: dict[str, float | None] | None = None, cohort_size: int = 0) -> str:
    """The report (module docstring); ``medians``: the cohort's median per metric key, or None."""
    who = r.trainee or "(no trainee recorded)"
    task = r.task_settings
    score = r.skill.get("task_score")
    head = [
        f"<h1>{_e(who)} · {_e(r.task or 'free session')}</h1>",
        f"<p>{_e(r.date or 'no date')} · {r.duration_s:.0f} s · {_e(r.path.name)}</p>",
    ]
    if r.notes:
        head.append(f"<div class=notes>{_e(r.notes)}</div>")
    box = f"<p>{_e(objective(task))}</p>"
    if score is not None:
        box += f"<p><span class=score>{score:.0f} %</span> {_e(outcome_words(r))}</p>"
    elif task.get("name"):
        box += f"<p>{_e(outcome_words(r))}</p>"
    parts = [*head, "<h2>Task and outcome</h2>", f'<div class=outcome id="outcome">{box}</div>']
    listed = moments(r)
    parts.append("<h2>Force on the tissue</h2>")
    if r.series is not None:
        parts.append(_img(plots.figure_png(*timeline(r)), "force on the tissue over time, with the limit"))
    parts.append(
        '<ol class=moments id="moments">'
        + "".join(f"<li>at {m.start_s:.1f} s: {_e(m.words)}</li>" for m in listed)
        + "</ol>"
        if listed
        else "<p>Nothing to point at: no force above the limit, no interruption of the force feedback.</p>"
    )
    parts.append("<h2>Skill metrics</h2>")
    header = ["metric", "this session"] + ([f"cohort median ({cohort_size})"] if medians else [])
    rows = []
    for key, words, unit in METRICS:
        row = [_e(f"{words} ({unit})" if unit else words), _value(key, r.skill.get(key))]
        if medians:
            row.append(_value(key, medians.get(key)))
        rows.append(row)
    parts.append(fit(table(header, rows, id="metrics")))
    parts.append("<h2>Contacts</h2>")
    parts.append(
        fit(
            table(
                ("#", "start [s]", "duration [s]", "peak [N]", "mean [N]", f"over {r.force_limit_N:g} N [s]"),
                [
                    (
                        str(i + 1),
                        _num(c.start_s),
                        _num(c.duration_s),
                        _num(c.peak_N),
                        _num(c.mean_N),
                        _num(c.over_limit_s),
                    )
                    for i, c in enumerate(r.contacts)
                ],
                id="contacts",
            )
        )
        if r.contacts
        else "<p>No contact.</p>"
    )
    if not medians:
        parts.append("<p>Give <code>--cohort DIR</code> to see the cohort's median beside each metric.</p>")
    parts.append('<div class=appendix id="appendix"><h2>Appendix: the session and the machine</h2>')
    parts.append(
        fit(
            table(
                ("measure", "value"),
                [(k, _e(v)) for k, v in _details(r) + summary_rows(r)],
                id="summary",
                text_columns=2,
            )
        )
    )
    parts.append(_engineering(r))
    parts.append("</div>")
    return document(f"Review: {who}, {r.task or r.name or r.path.name}", "".join(parts), REPORT_STYLE)


def _details(r: SessionReview) -> list[tuple[str, str]]:
    return [
        ("session", r.name or "–"),
        ("recording", r.path.name),
        ("estimator", r.estimator),
        ("complete", "yes" if r.complete else "no (recovered or cut short)"),
    ]


def _engineering(r: SessionReview) -> str:
    """The estimators, the paper's tables, the faults and every engineering plot."""
    parts = [
        "<h3>Estimators</h3>",
        fit(
            table(
                ("estimator", "samples", "force converged [s]", "torque converged [s]", "converged at end"),
                [
                    (
                        _e(e.name),
                        str(e.samples),
                        _num(e.converged_force_s),
                        _num(e.converged_torque_s),
                        "yes" if e.converged_at_end else "<span class=warn>no</span>",
                    )
                    for e in r.estimators
                ],
                id="estimators",
            )
        ),
    ]
    for e in r.estimators:
        parts.append(f"<h3>Compensation error, {_e(e.name)} (the paper's table; no contact, after convergence)</h3>")
        parts.append(
            fit(table(ERROR_HEADER, error_rows(e), id=f"errors-{_e(e.name)}"))
            if e.table
            else "<p>Not scored: the estimator never converged, or no contact-free sample followed.</p>"
        )
    shown = faults(r.events)
    parts.append("<h3>Faults and fail-safes</h3>")
    parts.append(
        fit(
            table(
                ("time [s]", "event", "message"),
                [(_num(r.t_s(ev.t_ns)), _e(ev.kind), _e(ev.message)) for ev in shown],
                id="events",
                text_columns=3,
            )
        )
        if shown
        else "<p>None.</p>"
    )
    if r.series is not None:
        for name in plots.PLOTS:
            parts.append(f"<h3>{_e(plots.TITLES[name])}</h3>{_img(plots.png(r, name), plots.TITLES[name])}")
    return "".join(parts)
