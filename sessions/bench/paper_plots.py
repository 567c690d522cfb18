"""``hapticlab bench paper --plots``: the paper's figures (Figs. 3–9) and the drift run's, as PNG files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2
from hapticlab.sessions.bench.paper_setup import AXES_F, AXES_T, REFERENCE_MASS_KG, SPEEDS_DEG_S

FIGURES = (
    "fig3_force_parameters.png",
    "fig4_torque_parameters.png",
    "fig5_force_compensation.png",
    "fig6_torque_compensation.png",
    "fig7_indentation.png",
    "fig8_rotation_104g.png",
    "fig9_rotation_metrics.png",
    "drift_contact.png",
)
"""The files :func:`write_plots` writes (an existing one is refused unless ``force``)."""


def write_plots(plots: dict[str, Any], folder: Path, force: bool = False) -> list[Path]:
    """The paper's figures as PNG files, each written atomically; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hapticlab.sessions.output import save_figure

    folder.mkdir(parents=True, exist_ok=True)
    written = []

    def save(fig, name):
        fig.tight_layout()
        written.append(save_figure(fig, folder / name, force, dpi=110))

    index, trace, truth = plots["identification"]
    for name, keys, units in (
        ("fig3_force_parameters.png", ("gravity_force_B", "bias_force_S"), ("N", "N")),
        ("fig4_torque_parameters.png", ("cog_S", "bias_torque_S"), ("m", "N·m")),
    ):
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
        for ax, key, unit in zip(axes, keys, units):
            for k, c in enumerate("rgb"):
                ax.plot(index + 1, trace[key][:, k], c, lw=1, label=f"{key}[{'xyz'[k]}]")
                ax.axhline(np.asarray(truth[key])[k], color=c, ls="--", lw=0.8)
            span = np.ptp(np.asarray(truth[key])) or 1.0
            mid = float(np.mean(truth[key]))
            ax.set_ylim(mid - 2.0 * span, mid + 2.0 * span)
            ax.set_xscale("log")
            ax.set_xlabel("sample (log scale)")
            ax.set_ylabel(unit)
            ax.set_title(f"{key} (dashed: truth)")
            ax.legend(fontsize=7, loc="upper right")
        save(fig, name)

    raw_f, comp_f, raw_t, comp_t = plots["poses"]
    for name, raw, comp, unit, axes_names in (
        ("fig5_force_compensation.png", raw_f, comp_f, "N", AXES_F),
        ("fig6_torque_compensation.png", raw_t, comp_t, "N·m", AXES_T),
    ):
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.4), sharex=True)
        for k, c in enumerate("rgb"):
            axes[0].plot(raw[:, k], c, lw=1, label=axes_names[k])
            axes[1].plot(comp[:, k], c, lw=1, label=axes_names[k])
        axes[0].set_title("raw")
        axes[1].set_title("compensated")
        for ax in axes:
            ax.set_xlabel("pose")
            ax.set_ylabel(unit)
            ax.legend(fontsize=7, loc="upper right")
        save(fig, name)

    t, raw, comp, contact = plots["indentation"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 6), sharex=True)
    for k, ax in enumerate(axes):
        ax.plot(t, raw[:, k], "r", lw=0.8, label="raw")
        ax.plot(t, comp[:, k], "b", lw=0.8, label="compensated")
        ax.fill_between(t, 0, 1, where=contact, transform=ax.get_xaxis_transform(), color="0.9", label="contact")
        ax.set_ylabel(f"{AXES_F[k]} (N)")
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    save(fig, "fig7_indentation.png")

    fig, ax = plt.subplots(figsize=(8, 3.6))
    for speed, (angle, magnitude) in plots["rotation"].items():
        ax.plot(angle, magnitude, lw=0.8, label=f"{speed} deg/s")
    ax.axhline(REFERENCE_MASS_KG * GRAVITY_M_S2, color="k", ls="--", lw=0.8, label="1.02 N")
    ax.set_xlabel("rotation (deg)")
    ax.set_ylabel("|contact force| (N)")
    ax.set_title("104 g mass on the tip, one turn per speed (¼ of Table I's noise)")
    ax.legend(fontsize=7, loc="upper right")
    save(fig, "fig8_rotation_104g.png")

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for ax, (key, title) in zip(axes, (("rotation_104g", "Table I noise"), ("rotation_104g_low_noise", "¼ noise"))):
        numbers = plots["rotation_metrics"][key]
        x = np.arange(len(SPEEDS_DEG_S))
        for k, (metric, label) in enumerate((("mae", "MAE"), ("max_ae", "Max AE"), ("std", "Std"))):
            ax.bar(x + (k - 1) * 0.27, [numbers[str(v)][metric] for v in SPEEDS_DEG_S], 0.27, label=label)
        ax.set_xticks(x, [f"{v} deg/s" for v in SPEEDS_DEG_S])
        ax.set_title(f"104 g mass, {title}")
        ax.set_ylabel("N")
        ax.set_ylim(0, 1.25 * max(numbers[str(v)]["max_ae"] for v in SPEEDS_DEG_S))
        ax.legend(fontsize=7, loc="upper right", ncol=3)
    save(fig, "fig9_rotation_metrics.png")

    t, truth_f, comp, contact, touching = plots["drift"]
    fig, ax = plt.subplots(figsize=(10, 3.4))
    ax.plot(t, np.linalg.norm(truth_f, axis=1), "k", lw=0.8, label="true contact")
    ax.plot(t, np.linalg.norm(comp, axis=1), "b", lw=0.6, label="rls |contact force|")
    ax.fill_between(
        t,
        0,
        1,
        where=contact & ~touching,
        transform=ax.get_xaxis_transform(),
        color="mistyrose",
        label="refused as contact, no contact",
    )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("N")
    ax.set_title("bias drifting 0.5 N/min, indentation every 10 s")
    ax.legend(fontsize=7, loc="upper left")
    save(fig, "drift_contact.png")
    return written
