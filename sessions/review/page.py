"""Reviews as one self-contained HTML page: a session's report, or (``cohort_page.py``) a cohort's.

The plots are embedded as PNG data URIs and the style is inline, so the page
is one file an instructor can mail, archive or open offline. Every text that
came from a recording or a config (names, notes, event messages) is escaped.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Sequence

from hapticlab.sessions.review import plots
from hapticlab.sessions.review.figures import AXES
from hapticlab.sessions.review.summary import SessionReview, faults

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; padding: 0 1em; max-width: 1000px; color: #222; }
h1 { font-size: 1.5em; overflow-wrap: anywhere; }
h2 { font-size: 1.15em; margin-top: 1.8em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; text-align: right; }
th { background: #f2f2f2; } td.text, th.text { text-align: left; }
.warn { color: #b00; } img { max-width: 100%; height: auto; }
.notes { white-space: pre-wrap; background: #f8f8f8; padding: 0.6em; }
.fit { max-width: 100%; overflow-x: auto; } .nowrap { white-space: nowrap; }
"""
"""The pages' style. ``fit``: a table box no wider than the page, scrolling sideways on its own when a
narrow window cannot hold the table (the page never does)."""


def _e(value) -> str:
    return html.escape(str(value))


def _num(x, digits: int = 2, unit: str = "") -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}{unit}"


def table(header: Sequence[str], rows: Iterable[Sequence[str]], id: str = "", text_columns: int = 1) -> str:
    """An HTML table (cells already escaped); the first ``text_columns`` columns left-aligned."""

    def cells(values, tag):
        return "".join(f"<{tag}{' class=text' if i < text_columns else ''}>{v}</{tag}>" for i, v in enumerate(values))

    body = "".join(f"<tr>{cells(r, 'td')}</tr>" for r in rows)
    attr = f' id="{id}"' if id else ""
    return f"<table{attr}><thead><tr>{cells(header, 'th')}</tr></thead><tbody>{body}</tbody></table>"


def fit(table_html: str) -> str:
    """A table in a ``fit`` box (:data:`STYLE`): it fits the page, or scrolls inside the box on a phone."""
    return f"<div class=fit>{table_html}</div>"


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{_e(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def document(title: str, body: str) -> str:
    return (
        "<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>"
        f"<meta name=viewport content='width=device-width, initial-scale=1'><title>{_e(title)}</title>"
        f"<style>{STYLE}</style></head><body>{body}</body></html>\n"
    )


def session_page(r: SessionReview) -> str:
    """One session's report as a self-contained HTML page."""
    who = r.trainee or "(no trainee recorded)"
    parts = [
        f"<h1>Session review: {_e(r.name or r.path.name)}</h1>",
        table(
            ("session", ""),
            [
                (k, _e(v))
                for k, v in (
                    ("trainee", who),
                    ("task", r.task or "–"),
                    ("date", r.date or "–"),
                    ("recording", r.path.name),
                    ("duration", f"{r.duration_s:.1f} s"),
                    ("estimator", r.estimator),
                    ("complete", "yes" if r.complete else "no (recovered or cut short)"),
                )
            ],
            id="who",
            text_columns=2,
        ),
    ]
    if r.notes:
        parts.append(f"<div class=notes>{_e(r.notes)}</div>")
    parts.append("<h2>Summary</h2>")
    parts.append(table(("measure", "value"), [(k, _e(v)) for k, v in summary_rows(r)], id="summary", text_columns=2))
    parts.append("<h2>Contacts</h2>")
    parts.append(
        table(
            ("#", "start [s]", "duration [s]", "peak [N]", "mean [N]", f"over {r.force_limit_N:g} N [s]"),
            [
                (str(i + 1), _num(c.start_s), _num(c.duration_s), _num(c.peak_N), _num(c.mean_N), _num(c.over_limit_s))
                for i, c in enumerate(r.contacts)
            ],
            id="contacts",
        )
        if r.contacts
        else "<p>No contact.</p>"
    )
    parts.append("<h2>Estimators</h2>")
    parts.append(
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
    )
    for e in r.estimators:
        parts.append(f"<h2>Compensation error, {_e(e.name)} (the paper's table; no contact, after convergence)</h2>")
        parts.append(
            table(
                (
                    "axis",
                    "MAE before",
                    "Max AE before",
                    "Std before",
                    "MAE after",
                    "Max AE after",
                    "Std after",
                    "MAE comp. %",
                ),
                error_rows(e),
                id=f"errors-{_e(e.name)}",
            )
            if e.table
            else "<p>Not scored: the estimator never converged, or no contact-free sample followed.</p>"
        )
    parts.append("<h2>Faults and fail-safes</h2>")
    shown = faults(r.events)
    parts.append(
        table(
            ("time [s]", "event", "message"),
            [(_num(r.t_s(ev.t_ns)), _e(ev.kind), _e(ev.message)) for ev in shown],
            id="events",
            text_columns=0,
        )
        if shown
        else "<p>None.</p>"
    )
    if r.series is not None:
        for name in plots.PLOTS:
            parts.append(f"<h2>{_e(plots.TITLES[name])}</h2>{_img(plots.png(r, name), plots.TITLES[name])}")
    return document(f"Review: {r.name or r.path.name}, {who}", "".join(parts))


def summary_rows(r: SessionReview) -> list[tuple[str, str]]:
    """The summary as (measure, value) lines: what the terminal and the page both show."""
    return [
        (
            "sensor",
            f"{r.samples} samples at {r.sensor_rate_hz:.0f} Hz; {r.lost_samples} lost, {r.bad_samples} "
            "flagged or non-finite",
        ),
        ("kinematics", f"{r.poses} poses at {r.kinematics_rate_hz:.0f} Hz"),
        ("contacts", f"{len(r.contacts)}, {r.contact_s:.2f} s in contact"),
        ("peak contact force", _num(r.peak_force_N, 2, " N")),
        (f"time over {r.force_limit_N:g} N", f"{r.over_limit_s:.2f} s"),
        ("haptic force on", f"{r.haptic_on_s:.1f} s of {r.duration_s:.1f} s"),
        ("faults and fail-safes", str(len(faults(r.events)))),
    ] + (
        []
        if r.port_energy_max_J is None
        else [
            (
                "haptic port (passivity)",
                f"most energy put into the hand {r.port_energy_max_J:.3f} J (passive: ≤ 0); damping added on "
                f"{100 * (r.damping_share or 0.0):.0f} % of ticks",
            )
        ]
    )


def error_rows(e) -> list[tuple[str, ...]]:
    """The paper's table of one estimator, a row per axis (N or N·m)."""
    return [
        (
            axis.upper(),
            *(
                _num(e.table[axis][key], 3)
                for key in ("mae_before", "max_before", "std_before", "mae_after", "max_after", "std_after")
            ),
            _num(e.table[axis]["mae_comp_pct"], 1),
        )
        for axis in AXES
    ]
