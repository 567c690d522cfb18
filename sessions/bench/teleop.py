"""``hapticlab bench teleop``: is force feedback stable, and what does keeping it passive cost?

The ``teleop-sim`` preset closes the loop hand → master → robot → tissue → force → hand in process (a
simulated master with a hand on it, ``plugins/haptics/sim_master.py``): after the calibration tour the hand
presses the tool into tissue, holds and lets go. Each run sets the link's one-way delay
(``teleop.delay_s``), the passivity controller (``teleop.passivity``) and the tissue's stiffness, and reads
from the recording:

* **max energy**: the largest energy the haptic port had put into the hand, ``max_t Σ F_D · v_D Δt`` (J),
  computed here from the recorded commands and handle velocities (each command's force times the velocity its
  tick ended at), not from the controller's own account: > 0 is an active port (it gave the hand more
  than the hand put in);
* **oscillation**: the standard deviation of the felt force in steady contact (the hold, from 0.5 s after
  the hand is down to its release), N, and the handle's peak-to-peak travel there, mm;
* **transparency**: the RMS difference, in the same window, between the force the hand felt and the contact
  force the robot's side estimated (the primary estimator's, before the link), N;
* **controller active**: the share of the session's ticks the controller added damping, and in brackets the
  share it added its cap (``max_damping``: a fixed damper then, not the least damping that would do).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import read_recording

DELAYS_S = (0.0, 0.03, 0.1, 0.3)
"""One-way delays, s: none, a UR's ``servoj`` look-ahead, a remote link, a long one."""
STIFFNESSES = (300.0, 3000.0)
"""The tissue's stiffness, N/m: soft tissue, and a stiff one (a tendon, muscle under tension)."""
PRESET = "teleop-sim"


def run(delay_s: float, passivity: str, stiffness: float) -> dict[str, Any]:
    """One ``teleop-sim`` session: the numbers of the module docstring, and the time series for the plots."""
    config, _ = load_config(PRESET)
    config = apply_settings(config, {"teleop.delay_s": delay_s, "teleop.passivity": passivity})
    config["world"]["contacts"][0]["stiffness"] = stiffness
    with tempfile.TemporaryDirectory() as folder:
        result = run_session(build_session(config), out=Path(folder) / "teleop.mcap")
        rec = read_recording(result.path)
    t0 = result.events[0].t_ns
    commands = rec.topics["/haptic/command"][:-1]  # (the session's final zero aside)
    states = rec.topics["/haptic/state"]
    n = min(len(commands), len(states))
    t = (np.array([t for t, _ in commands[:n]]) - t0) * 1e-9
    force = np.array([m["force_D"] for _, m in commands[:n]])
    v = np.array([m["v_DHo_D"] for _, m in states[:n]])
    p = np.array([m["pose"]["p_DoHo_D"] for _, m in states[:n]])
    dt = np.diff(t, append=t[-1])
    energy = np.concatenate([[0.0], np.cumsum(np.einsum("ij,ij->i", force[:-1], v[1:]) * dt[:-1])])
    haptic = config["haptic"]
    down = haptic["press_at"] + haptic["ramp"]
    hold = (t >= down + 0.5) & (t < down + haptic["hold"])
    felt = np.linalg.norm(force, axis=1)
    est = rec.estimates(config["estimator"]["name"])
    contact = np.interp(t, (est.t_ns - t0) * 1e-9, np.linalg.norm(est.contact_force_S, axis=1))
    damping = np.array([m["damping"] for _, m in rec.topics["/haptic/passivity"]])
    return {
        "max_energy_J": float(energy.max()),
        "force_std_N": float(felt[hold].std()),
        "handle_travel_mm": float(np.ptp(p[hold, 2]) * 1e3),
        "felt_N": float(felt[hold].mean()),
        "contact_N": float(contact[hold].mean()),
        "transparency_rms_N": float(np.sqrt(np.mean((felt[hold] - contact[hold]) ** 2))),
        "controller_active": float(np.mean(damping > 0)) if len(damping) else 0.0,
        "controller_capped": float(np.mean(damping >= config["teleop"]["max_damping"])) if len(damping) else 0.0,
        "series": {"t": t, "force_z": force[:, 2], "energy": energy, "contact": contact},
    }


def bench_teleop(progress: Callable[[str], None] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
    """Every delay × passivity × stiffness: the numbers (JSON-ready, keyed "<k> N/m" → "<delay> s" → on/off),
    and the time series of the worst case (the largest energy with the controller off) with and without it."""
    out: dict[str, Any] = {}
    series: dict[str, Any] = {}
    worst = -np.inf
    for stiffness in STIFFNESSES:
        for delay_s in DELAYS_S:
            runs = {}
            for passivity in ("off", "on"):
                if progress:
                    progress(f"{stiffness:g} N/m, {delay_s * 1e3:g} ms, passivity {passivity}")
                runs[passivity] = run(delay_s, passivity, stiffness)
            if runs["off"]["max_energy_J"] > worst:
                worst = runs["off"]["max_energy_J"]
                series = {"label": f"{stiffness:g} N/m, {delay_s * 1e3:g} ms each way", **runs}
            out.setdefault(f"{stiffness:g} N/m", {})[f"{delay_s:g} s"] = {
                k: {key: value for key, value in r.items() if key != "series"} for k, r in runs.items()
            }
    return out, series


COLUMNS = (
    "tissue",
    "delay each way",
    "passivity",
    "max energy into the hand (J)",
    "force std in contact (N)",
    "handle travel (mm)",
    "felt / contact (N)",
    "transparency RMS (N)",
    "controller active (capped)",
)
"""The table's columns (``bench teleop``'s printout and docs/results.md)."""


def table_rows(out: dict[str, Any], fmt: Callable[[Any, int], str]) -> list[tuple[tuple[str, ...], bool]]:
    """The rows of ``bench_teleop``'s numbers under :data:`COLUMNS`, each with whether it ends a stiffness,
    numbers written with ``fmt(value, digits)``."""
    rows: list[tuple[tuple[str, ...], bool]] = []
    for stiffness, delays in out.items():
        for k, (delay, runs) in enumerate(delays.items()):
            for passivity, r in runs.items():
                first = passivity == "off"
                row = (
                    stiffness if k == 0 and first else "",
                    f"{float(delay.removesuffix(' s')) * 1e3:g} ms" if first else "",
                    passivity,
                    fmt(r["max_energy_J"], 3),
                    fmt(r["force_std_N"], 2),
                    fmt(r["handle_travel_mm"], 1),
                    f"{fmt(r['felt_N'], 2)} / {fmt(r['contact_N'], 2)}",
                    fmt(r["transparency_rms_N"], 2),
                    f"{100 * r['controller_active']:.0f} % ({100 * r.get('controller_capped', 0.0):.0f} %)",
                )
                rows.append((row, passivity == "on" and k == len(delays) - 1))
    return rows


def write_plot(series: dict[str, Any], path: Path, force: bool = False) -> Path:
    """Force and port energy against time, with and without the controller, for ``series``: a PNG written
    atomically (an existing file only with ``force``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hapticlab.sessions.output import save_figure

    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for passivity, style in (("off", "tab:red"), ("on", "tab:blue")):
        s = series[passivity]["series"]
        top.plot(s["t"], s["force_z"], color=style, lw=0.8, label=f"felt (passivity {passivity})")
        bottom.plot(s["t"], s["energy"], color=style, lw=1.0, label=f"passivity {passivity}")
    top.plot(series["on"]["series"]["t"], series["on"]["series"]["contact"], color="k", lw=0.8, ls="--",
             label="contact, robot's side (on)")  # fmt: skip
    top.set_ylabel("force along D's z, N")
    top.legend(loc="upper left", fontsize=8)
    top.set_title(f"teleop-sim, {series['label']}: the force on the hand and the energy the port gave it")
    bottom.axhline(0.0, color="0.5", lw=0.5)
    bottom.set_ylabel("energy into the hand, J")
    bottom.set_xlabel("session time, s")
    bottom.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path, force, dpi=110)
