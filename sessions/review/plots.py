"""A reviewed session's plots as PNG: raw against compensated wrench, convergence, contacts, haptic command.

Each plot draws the time-binned envelopes of :class:`~.summary.Series` (the
band is every sample's min to max in a bin, the line the bin's mean), so a
15-minute session and a 15-second one cost the same to draw and no spike is
hidden by decimation.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from hapticlab.sessions.output import atomic_output, check_plots_folder
from hapticlab.sessions.review.figures import AXES, Envelope
from hapticlab.sessions.review.summary import SessionReview

PLOTS = ("wrench", "convergence", "contact", "command")
"""The plots, in the order a report shows them (file ``<name>.png``)."""
TITLES = {
    "wrench": "Raw against compensated wrench",
    "convergence": "Parameter convergence",
    "contact": "Contact force and contacts",
    "command": "Haptic command",
}


def _figure(rows: int, height: float = 2.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, 1, figsize=(10, 0.6 + height * rows), sharex=True, squeeze=False)
    return plt, fig, axes[:, 0]


def _band(ax, env: Envelope, col: int, color: str, label: str) -> None:
    t = env.t_s
    ok = env.count[:, col] > 0
    ax.fill_between(t[ok], env.lo[ok, col], env.hi[ok, col], color=color, alpha=0.25, linewidth=0)
    ax.plot(t[ok], env.mean[ok, col], color=color, linewidth=0.9, label=label)


def _shade_contacts(ax, r: SessionReview) -> None:
    for c in r.contacts:
        ax.axvspan(c.start_s, c.start_s + c.duration_s, color="tab:orange", alpha=0.12, linewidth=0)


def _limits(ax, series, k: int, settled_s: float | None) -> None:
    """Y limits from the raw reading and the estimate once converged (its first seconds can be far off
    the scale while it identifies the tool; they are drawn, clipped)."""
    after = series.compensated.t_s >= (settled_s if settled_s is not None else np.inf)
    parts = [series.raw.lo[:, k], series.raw.hi[:, k], series.compensated.lo[after, k], series.compensated.hi[after, k]]
    values = np.concatenate(parts)
    values = values[np.isfinite(values)]
    if len(values):
        lo, hi = float(values.min()), float(values.max())
        pad = 0.08 * max(hi - lo, 1e-3)
        ax.set_ylim(lo - pad, hi + pad)


def wrench(r: SessionReview):
    assert r.series is not None  # drawn only for a review made with plots (write_plots and the page check)
    plt, fig, axes = _figure(6, 1.4)
    units = ["N"] * 3 + ["N·m"] * 3
    primary = r.primary
    settled = (
        [primary.converged_force_s if k < 3 else primary.converged_torque_s for k in range(6)]
        if primary
        else [None] * 6
    )
    for k, ax in enumerate(axes):
        _band(ax, r.series.raw, k, "0.45", "raw (sensor)")
        _band(ax, r.series.compensated, k, "tab:blue", f"compensated ({r.estimator})")
        _shade_contacts(ax, r)
        _limits(ax, r.series, k, settled[k])
        ax.set_ylabel(f"{AXES[k].upper()} [{units[k]}]")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{TITLES['wrench']} in S (contacts shaded)")
    return plt, fig


def convergence(r: SessionReview):
    assert r.series is not None  # drawn only for a review made with plots (write_plots and the page check)
    names = list(r.series.params[0][1]) if r.series.params else []
    plt, fig, axes = _figure(max(len(names), 1), 1.6)
    t = np.array([p[0] for p in r.series.params])
    for ax, name in zip(axes, names):
        values = np.array([np.ravel(p[1].get(name, np.nan)) for p in r.series.params], dtype=float)
        for k in range(values.shape[1]):
            ax.plot(t, values[:, k], linewidth=1.0, label="xyz"[k] if values.shape[1] == 3 else str(k))
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=7, ncol=3)
    primary = r.primary
    for ax in axes:
        for when, style in (
            (primary.converged_force_s if primary else None, "--"),
            (primary.converged_torque_s if primary else None, ":"),
        ):
            if when is not None:
                ax.axvline(when, color="k", linestyle=style, linewidth=0.8)
    if not names:
        axes[0].text(0.5, 0.5, "no parameters recorded", ha="center", va="center", transform=axes[0].transAxes)
    axes[-1].set_xlabel("time [s]  (dashed: force stage converged; dotted: torque stage)")
    fig.suptitle(f"{TITLES['convergence']} ({r.estimator})")
    return plt, fig


def contact(r: SessionReview):
    assert r.series is not None  # drawn only for a review made with plots (write_plots and the page check)
    plt, fig, axes = _figure(1, 3.0)
    ax = axes[0]
    _band(ax, r.series.contact_force, 0, "tab:blue", "‖contact force‖")
    _shade_contacts(ax, r)
    ax.axhline(
        r.force_limit_N,
        color="tab:red",
        linestyle="--",
        linewidth=1.0,
        label=f"limit {r.force_limit_N:g} N ({r.over_limit_s:.2f} s over)",
    )
    ax.set_ylabel("force [N]")
    ax.set_xlabel("time [s]")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.suptitle(f"{TITLES['contact']}: {len(r.contacts)} contact(s), peak {r.peak_force_N:.2f} N")
    return plt, fig


def command(r: SessionReview):
    assert r.series is not None  # drawn only for a review made with plots (write_plots and the page check)
    port = r.series.passivity
    plt, fig, axes = _figure(3 if port is not None else 2, 1.8)
    env = r.series.command
    if env is None or not env.count.any():
        axes[0].text(0.5, 0.5, "no haptic commands recorded", ha="center", va="center", transform=axes[0].transAxes)
    else:
        _band(axes[0], env, 0, "tab:green", "‖force on the handle‖")
        ok = env.count[:, 1] > 0
        axes[1].fill_between(env.t_s[ok], 0, env.mean[ok, 1], color="tab:green", alpha=0.5, step="mid")
    axes[0].set_ylabel("force [N]")
    axes[1].set_ylabel("force on (share)")
    axes[1].set_ylim(-0.05, 1.05)
    title = f"{TITLES['command']}: on {r.haptic_on_s:.1f} of {r.duration_s:.1f} s"
    if port is not None:  # teleoperation: the port's energy (passive while ≤ 0) and the damping that kept it so
        _band(axes[2], port, 0, "tab:purple", "energy into the hand E(t)")
        axes[2].axhline(0.0, color="black", linewidth=0.6)
        axes[2].set_ylabel("E [J]")
        damping = axes[2].twinx()
        ok = port.count[:, 1] > 0
        damping.plot(port.t_s[ok], port.hi[ok, 1], color="tab:orange", linewidth=0.8, label="damping added")
        damping.set_ylabel("damping [N·s/m]")
        axes[2].legend(loc="upper left", fontsize=8)
        damping.legend(loc="upper right", fontsize=8)
        if r.port_energy_max_J is not None:
            title += f"; port energy at most {r.port_energy_max_J:.3f} J"
    axes[-1].set_xlabel("time [s]")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    return plt, fig


DRAW = {"wrench": wrench, "convergence": convergence, "contact": contact, "command": command}


def figure_png(plt, fig) -> bytes:
    """A finished matplotlib figure as PNG bytes (laid out tight, 90 dpi), closed."""
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def png(r: SessionReview, name: str) -> bytes:
    """One plot (a name of :data:`PLOTS`) as PNG bytes."""
    return figure_png(*DRAW[name](r))


def write_plots(r: SessionReview, folder: str | Path, force: bool = False) -> list[Path]:
    """Every plot as ``folder/<plot>.png`` (the folder is created); an existing figure is refused unless ``force``
    (checked before any is drawn)."""
    if r.series is None:
        raise ValueError("the review was made without plots (plots=False)")
    folder = check_plots_folder(folder, force, patterns=[f"{name}.png" for name in PLOTS])
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in PLOTS:
        with atomic_output(folder / f"{name}.png", force, label="--plots") as tmp:
            tmp.write_bytes(png(r, name))
        paths.append(folder / f"{name}.png")
    return paths
