"""Figures of ``hapticlab discrepancy``: where the residual lives, before and after each step.

One figure per model state (``00_baseline.png``, ``01_after_<effect>.png``,
...), each with the same six panels, so consecutive figures are the before and
after of a step:

* force residual against time (and the torque residual, last panel);
* the force residual's norm against angular speed and angular acceleration
  (points and the RMS per bin): a time lag grows with speed, inertia with
  acceleration;
* a sphere map: the direction of gravity in S (longitude, latitude) coloured
  by the force residual's norm: a mount rotation or a calibration error is a
  pattern over the sphere;
* the residual of each force axis against the predicted force on that axis
  (the load): a gain error is a slope.

And ``steps.png``: the RMS per axis after each step, beside the offline batch fit.
Samples the contact gate set aside are left out; large recordings are thinned
evenly for the scatter plots (the RMS per bin uses every sample).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.offline.metrics import rms
from hapticlab.sessions.output import save_figure

MAX_POINTS = 4000
COLORS = ("tab:red", "tab:green", "tab:blue")


def _binned_rms(x: np.ndarray, y: np.ndarray, bins: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Bin centres and RMS of y per bin of x (bins with fewer than 5 samples dropped)."""
    if len(x) < 10 or np.ptp(x) <= 0:
        return np.zeros(0), np.zeros(0)
    edges = np.linspace(x.min(), x.max(), bins + 1)
    k = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
    count = np.bincount(k, minlength=bins)
    total = np.bincount(k, weights=y**2, minlength=bins)
    ok = count >= 5
    centres = 0.5 * (edges[1:] + edges[:-1])
    return centres[ok], np.sqrt(total[ok] / count[ok])


def _slug(label: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_")


FIGURE_PATTERNS = ("[0-9][0-9]_*.png", "steps.png")
"""The files :func:`write_plots` writes (an existing one is refused unless ``force``)."""


def write_plots(result: dict[str, Any], folder: str | Path, force: bool = False) -> list[Path]:
    """Write the figures of a ``discrepancy`` result into ``folder`` (created), each atomically; the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)

    force_S = result["_stream"].samples.force_S
    kept = result["_kept"]
    states = result["_states"]
    motion = result["_motion"]
    rows = np.flatnonzero(kept)
    thin = rows[:: max(1, len(rows) // MAX_POINTS)]
    unit = "s" if motion.time_base == "seconds" else "row"
    written: list[Path] = []
    speed = np.linalg.norm(motion.w_E, axis=1) if motion.w_E is not None else None
    accel = np.linalg.norm(motion.alpha_E, axis=1) if motion.alpha_E is not None else None
    rms_rows = []  # each state's RMS per channel on the kept rows, for steps.png
    for i, state in enumerate(states):
        res = state.residual  # computed on reading (one state's arrays at a time)
        weight_S = state.weight_S
        norm_f = np.linalg.norm(res[:, :3], axis=1)
        rms_f = rms(res[rows, :3])
        rms_rows.append(np.concatenate([rms_f, rms(res[rows, 3:])]))
        fig, axes = plt.subplots(2, 3, figsize=(16, 9))
        fig.suptitle(
            f"{result['input']}: {state.label} — force RMS [{', '.join(f'{v:.3f}' for v in rms_f)}] N "
            f"on {len(rows)} samples"
        )
        ax = axes[0, 0]
        for k in range(3):
            ax.plot(motion.t[thin], res[thin, k], ".", ms=1.5, color=COLORS[k], label="xyz"[k])
        ax.set(title="force residual against time", xlabel=f"t ({unit})", ylabel="N")
        ax.legend(markerscale=6, loc="upper right")
        for ax, x, name, xunit in (
            (axes[0, 1], speed, "angular speed", "rad/s"),
            (axes[0, 2], accel, "angular acceleration", "rad/s²"),
        ):
            if x is None:
                ax.text(0.5, 0.5, "no time base: t counts rows", ha="center", va="center", transform=ax.transAxes)
                ax.set_title(f"|force residual| against {name}")
                continue
            ax.plot(x[thin], norm_f[thin], ".", ms=1.5, color="0.6")
            cx, cy = _binned_rms(x[rows], norm_f[rows])
            ax.plot(cx, cy, "-o", color="k", ms=3, label="RMS per bin")
            ax.set(title=f"|force residual| against {name}", xlabel=f"{name} ({xunit})", ylabel="N")
            ax.legend(loc="upper left")
        ax = axes[1, 0]
        g = weight_S / np.maximum(np.linalg.norm(weight_S, axis=1, keepdims=True), 1e-12)
        lon = np.degrees(np.arctan2(g[:, 1], g[:, 0]))
        lat = np.degrees(np.arcsin(np.clip(g[:, 2], -1, 1)))
        sc = ax.scatter(lon[thin], lat[thin], c=norm_f[thin], s=4, cmap="viridis")
        fig.colorbar(sc, ax=ax, label="|force residual| (N)")
        ax.set(
            title="gravity direction in S, coloured by |force residual|",
            xlabel="longitude (deg)",
            ylabel="latitude (deg)",
            xlim=(-180, 180),
            ylim=(-90, 90),
        )
        ax = axes[1, 1]
        predicted = force_S - res[:, :3]
        for k in range(3):
            ax.plot(predicted[thin, k], res[thin, k], ".", ms=1.5, color=COLORS[k], alpha=0.5)
            if len(rows) > 10:
                slope = np.polyfit(predicted[rows, k], res[rows, k], 1)[0]
                xs = np.linspace(predicted[rows, k].min(), predicted[rows, k].max(), 2)
                ax.plot(
                    xs,
                    slope * (xs - predicted[rows, k].mean()) + res[rows, k].mean(),
                    color=COLORS[k],
                    label=f"{'xyz'[k]}: slope {100 * slope:+.2f} %",
                )
        ax.set(
            title="force residual against load (predicted force, per axis)",
            xlabel="predicted force (N)",
            ylabel="residual (N)",
        )
        ax.legend(loc="upper left")
        ax = axes[1, 2]
        for k in range(3):
            ax.plot(motion.t[thin], res[thin, 3 + k], ".", ms=1.5, color=COLORS[k], label="xyz"[k])
        ax.set(title="torque residual against time", xlabel=f"t ({unit})", ylabel="N·m")
        ax.legend(markerscale=6, loc="upper right")
        fig.tight_layout()
        written.append(save_figure(fig, folder / f"{i:02d}_{_slug(state.label)}.png", force, dpi=90))

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    labels = [s.label for s in states]
    x = np.arange(len(states))
    for ax, offset, unit, key in ((axes[0], 0, "N", "rms_force_S"), (axes[1], 3, "N·m", "rms_torque_S")):
        values = np.array([r[offset : offset + 3] for r in rms_rows])
        for k in range(3):
            ax.bar(x + (k - 1) * 0.27, values[:, k], 0.27, color=COLORS[k], label="xyz"[k])
            ax.axhline(result["batch_fit"][key][k], color=COLORS[k], ls="--", lw=0.8)
        ax.set_xticks(x, labels, rotation=20, ha="right")
        ax.set(
            ylabel=f"RMS ({unit})",
            title=f"{'force' if offset == 0 else 'torque'} RMS per step (dashed: offline batch fit)",
        )
        ax.legend()
    fig.suptitle(result["input"])
    fig.tight_layout()
    written.append(save_figure(fig, folder / "steps.png", force, dpi=90))
    return written
