"""A cohort's learning curves: each trainee's sessions of a task against the cohort's percentiles.

One panel per task (columns) and key metric (rows, :data:`CURVES`); x is the
trainee's session of that task (``session``: 1, 2, ..., integer ticks), one
line per trainee, and behind them the cohort's median and 25–75 % band per
session, over the task's trainees who had that session (two at least: one
trainee is no cohort). Sessions without a trainee are grey crosses, not a line
and not in the band: their order says nothing of one person's progress.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hapticlab.sessions.review.skill_names import header

CURVES = ("task_score", "peak_force_N", "excess_force_events", "task_time_s")
"""The metrics drawn (a row of panels each, when some session has it)."""
TASKS_PER_FIGURE = 3
"""Tasks side by side in one figure (more make another figure): a panel stays ≥ 300 px wide at 90 dpi."""
NO_TASK = "(no task)"


def value(row: dict[str, Any], key: str) -> float:
    """A row's metric as a float, NaN when unknown."""
    x = row.get(key)
    return float(x) if isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) else math.nan


def band(rows: Sequence[dict[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """Session indexes and the (25, 50, 75) percentiles of ``key`` at each over the named trainees' rows.

    Returns (n, p) with p of shape (len(n), 3); a session index with fewer than two known values is NaN.
    """
    named = [r for r in rows if r.get("trainee")]
    n = np.arange(1, max((r["session"] for r in named), default=0) + 1)
    p = np.full((len(n), 3), np.nan)
    for i, k in enumerate(n):
        x = np.array([value(r, key) for r in named if r["session"] == k])
        x = x[np.isfinite(x)]
        if len(x) >= 2:
            p[i] = np.percentile(x, (25, 50, 75))
    return n, p


def learning_pngs(rows: Sequence[dict[str, Any]]) -> list[bytes]:
    """The learning curves as PNG images (one per :data:`TASKS_PER_FIGURE` tasks, 90 dpi); [] when nothing
    to draw."""
    import io

    figures = learning_figures(rows)  # (sets the Agg backend before pyplot is imported here)
    import matplotlib.pyplot as plt

    out = []
    for fig in figures:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=90)  # as plots.figure_png, whose tight_layout would cover the legend
        plt.close(fig)
        out.append(buf.getvalue())
    return out


def learning_figures(rows: Sequence[dict[str, Any]]) -> list:
    """The learning curves as matplotlib figures (rows of :func:`~.cohort.rows_of`, with ``session``)."""
    from hapticlab.sessions.review.cohort import order

    tasks: list[str] = []
    for row in sorted(rows, key=order):
        if (row.get("task") or "") not in tasks:
            tasks.append(row.get("task") or "")
    keys = [k for k in CURVES if any(math.isfinite(value(r, k)) for r in rows)]
    if not keys:
        return []
    trainees = sorted({r["trainee"] for r in rows if r.get("trainee")})
    return [
        _figure(rows, tasks[i : i + TASKS_PER_FIGURE], keys, trainees) for i in range(0, len(tasks), TASKS_PER_FIGURE)
    ]


def _figure(rows, tasks: list[str], keys: list[str], trainees: list[str]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    colours = plt.get_cmap("tab10" if len(trainees) <= 10 else "tab20")
    colour = {t: colours(i % colours.N) for i, t in enumerate(trainees)}
    fig, axes = plt.subplots(
        len(keys), len(tasks), figsize=(3.6 * len(tasks) + 1.2, 2.3 * len(keys) + 0.8), squeeze=False, sharex="col"
    )
    handles: dict[str, Any] = {}
    for j, task in enumerate(tasks):
        of_task = [r for r in rows if (r.get("task") or "") == task]
        last = max(r["session"] for r in of_task)
        for i, key in enumerate(keys):
            ax = axes[i, j]
            n, p = band(of_task, key)
            if np.isfinite(p).any():
                handles["cohort 25–75 %"] = ax.fill_between(n, p[:, 0], p[:, 2], color="0.85", linewidth=0)
                (handles["cohort median"],) = ax.plot(n, p[:, 1], color="0.35", linestyle="--", linewidth=1.2)
            for trainee in trainees:
                mine = [r for r in of_task if r.get("trainee") == trainee]
                if mine:
                    (handles[trainee],) = ax.plot(
                        [r["session"] for r in mine], [value(r, key) for r in mine], marker="o", color=colour[trainee]
                    )
            unnamed = [r for r in of_task if not r.get("trainee")]
            if unnamed:
                handles["(no trainee)"] = ax.scatter(
                    [r["session"] for r in unnamed], [value(r, key) for r in unnamed], marker="x", color="0.5"
                )
            if last <= 12:  # every session its tick (MaxNLocator gives halves on a one-session axis)
                ax.set_xticks(range(1, last + 1))
            else:
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.set_xlim(0.5, last + 0.5)
            if key == "excess_force_events":
                ax.yaxis.set_major_locator(MaxNLocator(integer=True))
            if not any(math.isfinite(value(r, key)) for r in of_task):
                ax.text(0.5, 0.5, "not measured", transform=ax.transAxes, ha="center", va="center", color="0.5")
                ax.set_yticks([])
            ax.grid(alpha=0.3)
            if j == 0:
                ax.set_ylabel(header(key), fontsize=9)
            if i == 0:
                ax.set_title(_plain(task or NO_TASK))
        axes[-1, j].set_xlabel("the trainee's session of this task")
    labels = [k for k in ("cohort 25–75 %", "cohort median", *trainees, "(no trainee)") if k in handles]
    fig.legend(
        [handles[k] for k in labels],
        [_plain(k) for k in labels],
        loc="lower center",
        ncol=min(len(handles), 6),
        fontsize=8,
        frameon=False,
    )
    legend_in = 0.25 * math.ceil(len(handles) / 6) + 0.1  # its rows of 8 pt text, in
    fig.tight_layout(rect=(0, legend_in / fig.get_figheight(), 1, 1))  # room for the legend
    return fig


def _plain(text: str) -> str:
    """A name as matplotlib should draw it: as written (a ``$`` would start its maths: ``$x_{$`` raised)."""
    return text.replace("$", r"\$")
