"""The instructor's force timeline: the tool–tissue force against the task's limit, with what happened said in
words on the plot and beside it (excessive force, force feedback lost, the trainee's marks).

:func:`moments` lists the moments an instructor would talk about, in plain words, in time order;
:func:`timeline` draws the contact force (the primary estimator's, time-binned: ``figures.Envelope``) with
the limit and each moment marked and numbered, so the list below the plot reads with it on a phone too.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from hapticlab.sessions.review.session import SessionReview, haptic_on_runs


@dataclass(frozen=True)
class Moment:
    """Something an instructor would point at: when (s from the start), for how long (s), what, in words."""

    start_s: float
    duration_s: float
    kind: str  # "excess", "dropout", "mark"
    words: str


def dropouts(r: SessionReview) -> list[tuple[float, float, str]]:
    """(start s, duration s, why) of each time the haptic force went off after it first came on (every one,
    however short: the trainee's hand was on the device and the force it felt went to zero): the gaps between
    the runs of ``haptic_on_runs``, and the time after the last to the end when an event turned it off."""
    end_ns = r.start_ns + round(r.duration_s * 1e9)
    runs = haptic_on_runs(r.events, end_ns)
    out = [(r.t_s(off), (on_next - off) / 1e9, why) for (_, off, why), (on_next, _, _) in pairwise(runs)]
    if runs and runs[-1][2]:  # off to the end
        out.append((r.t_s(runs[-1][1]), max(0.0, (end_ns - runs[-1][1]) / 1e9), runs[-1][2]))
    return out


def _in_contact(r: SessionReview, start: float, end: float) -> bool:
    return any(c.start_s < end and start < c.start_s + c.duration_s for c in r.contacts)


def moments(r: SessionReview) -> list[Moment]:
    """The session's moments in time order, each said in words."""
    out = [
        Moment(s, d, "excess", f"force above the {r.force_limit_N:g} N limit for {d:.2f} s, peaking at {p:.1f} N")
        for s, d, p in r.excess_events
    ]
    for s, d, why in dropouts(r):
        during = " during a contact" if _in_contact(r, s, s + d) else ""
        out.append(Moment(s, d, "dropout", f"force feedback off for {d:.2f} s{during}: {why}"))
    mark = r.outcome.get("mark_s")
    if mark is not None:
        error = r.outcome.get("mark_error_m")
        where = f", {1e3 * error:.1f} mm from the inclusion" if error is not None else ""
        out.append(Moment(mark, 0.0, "mark", f"the trainee marked the inclusion here{where}"))
    return sorted(out, key=lambda m: m.start_s)


COLORS = {"excess": "tab:red", "dropout": "0.35", "mark": "tab:green"}


def timeline(r: SessionReview):
    """(plt, fig): the force timeline with the limit and the numbered moments."""
    assert r.series is not None  # drawn only for a review made with plots
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.6))
    env = r.series.contact_force
    ok = env.count[:, 0] > 0
    ax.fill_between(env.t_s[ok], env.lo[ok, 0], env.hi[ok, 0], color="tab:blue", alpha=0.25, linewidth=0)
    ax.plot(env.t_s[ok], env.mean[ok, 0], color="tab:blue", linewidth=1.0, label="force on the tissue")
    ax.axhline(r.force_limit_N, color="tab:red", linestyle="--", linewidth=1.0, label=f"limit {r.force_limit_N:g} N")
    band = r.task_settings.get("band") if r.task_settings.get("name") == "retraction" else None
    if band:
        ax.axhspan(band[0], band[1], color="tab:green", alpha=0.1, label=f"band {band[0]:g}–{band[1]:g} N")
    top = max(float(np.nanmax(env.hi[ok, 0])) if ok.any() else 0.0, r.force_limit_N) * 1.15 + 0.1
    for i, m in enumerate(moments(r), start=1):
        color = COLORS[m.kind]
        if m.duration_s > 0:
            ax.axvspan(m.start_s, m.start_s + m.duration_s, color=color, alpha=0.18, linewidth=0)
        else:
            ax.axvline(m.start_s, color=color, linewidth=1.2)
        ax.annotate(
            str(i), (m.start_s, top * 0.93), ha="center", fontsize=10, color="white",
            bbox={"boxstyle": "circle,pad=0.25", "fc": color, "ec": "none"},
        )  # fmt: skip
    ax.set_ylim(0, top)
    ax.set_xlim(0, r.duration_s)
    ax.set_xlabel("time since the session started [s]")
    ax.set_ylabel("force [N]")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=9)
    return plt, fig
