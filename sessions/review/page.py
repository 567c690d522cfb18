"""The review pages' HTML parts: style, tables, embedded images (a session's report: ``report.py``; a cohort's:
``cohort_page.py``), and the summary and paper's rows the terminal shows too.

The plots are embedded as PNG data URIs and the style is inline, so the page
is one file an instructor can mail, archive or open offline. Every text that
came from a recording or a config (names, notes, event messages) is escaped.
"""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Iterable, Sequence

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


def document(title: str, body: str, style: str = "") -> str:
    """A self-contained page: :data:`STYLE` and a page's own ``style`` after it."""
    return (
        "<!DOCTYPE html>\n<html lang=en><head><meta charset=utf-8>"
        f"<meta name=viewport content='width=device-width, initial-scale=1'><title>{_e(title)}</title>"
        f"<style>{STYLE}{style}</style></head><body>{body}</body></html>\n"
    )


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


ERROR_HEADER = (
    "axis",
    "MAE before",
    "Max AE before",
    "Std before",
    "MAE after",
    "Max AE after",
    "Std after",
    "MAE comp. %",
)
"""The paper's table's columns (:func:`error_rows`'s cells), as the terminal and the report head it."""


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
