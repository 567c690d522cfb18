"""``hapticlab bench faults``: every injected fault through the real run loop, and what reached the hand.

Each fault of ``plugins/simworld/faults.py`` is injected into the demo session
(simulated sensor and robot, the force on from about 2.2 s, a random tour that
keeps turning the tool) at ``FAULT_START_S``, and the same session is run
once without it. Both runs share every seed, so the difference between their
haptic commands is the force the fault alone put on the trainee's hand:

* **made-up force**: from the fault's start until the force is back (zero, or
  the clean run's force), the largest part of the fault run's force that the
  clean run's force, scaled by anything in [0, 1], cannot explain, N: a force
  the contact does not give. (A force zeroed, or ramping back up to the true
  one, makes up nothing: missing force is safe.)
* **over 0.5 N for**: how long the made-up force was above ``MADE_UP_BOUND_N``, s, summed over the
  commands (each lasting a loop period);
* **detected after**: from the fault's start to the first zero command whose
  reason names a fault, s (None: never);
* **zero after detection**: from that detection to the first zero command, s
  (zero is immediate by construction; measured all the same);
* **event**: the first fault event recorded after the start.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.live.gate import WARMING_UP
from hapticlab.sessions.recording import read_recording

FAULT_START_S = 4.0
MADE_UP_BOUND_N = 0.5
"""The made-up force a single fault may put on the hand, N (about what a trainee starts to notice against a 2-4 N
contact): the time above it is reported."""
DURATION_S = 7.0
FAULTS: dict[str, dict[str, Any]] = {
    "sensor spike +1000 N, 20 ms": {"kind": "sensor_spike", "force": [1000.0, 0.0, 0.0], "duration": 0.02},
    "sensor NaN, 200 ms": {"kind": "sensor_nan", "duration": 0.2},
    "sensor saturated, 200 ms": {"kind": "sensor_saturated", "duration": 0.2},
    "sensor dropout, 500 ms": {"kind": "sensor_dropout", "duration": 0.5},
    "sensor bias step +2 N": {"kind": "sensor_bias_step", "force": [2.0, 0.0, 0.0]},
    "kinematics frozen, 2 s": {"kind": "kinematics_freeze", "duration": 2.0},
    "kinematics 200 ms late, 2 s": {"kind": "kinematics_delay", "delay": 0.2, "duration": 2.0},
    "kinematics late by 0→200 ms over 0.5 s, 2 s": {
        "kind": "kinematics_delay",
        "delay": 0.2,
        "ramp": 0.5,
        "duration": 2.0,
    },
    "kinematics dropout, 500 ms": {"kind": "kinematics_dropout", "duration": 0.5},
    "sensor spike +60 N, 30 ms (within range)": {"kind": "sensor_spike", "force": [60.0, 0.0, 0.0], "duration": 0.03},
    "sensor bias ramp +3 N over 6 s, then held": {
        "kind": "sensor_bias_step",
        "force": [3.0, 0.0, 0.0],
        "ramp": 6.0,
        "session_s": 12.0,
    },
    "sensor bias step +2 N during a contact": {
        "kind": "sensor_bias_step",
        "force": [2.0, 0.0, 0.0],
        "start": 6.75,
        "session_s": 9.0,
    },
    "sensor stuck, 2 s": {"kind": "sensor_stuck", "duration": 2.0},
    "sensor offset +5 N for 1 s": {"kind": "sensor_bias_step", "force": [5.0, 0.0, 0.0], "duration": 1.0},
    "sensor offset +5 N for 1 s, during a contact": {
        "kind": "sensor_bias_step",
        "force": [5.0, 0.0, 0.0],
        "duration": 1.0,
        "start": 6.5,
        "session_s": 9.0,
    },
    "sensor offset ramping +6 N over 0.5 s, during a contact": {
        "kind": "sensor_bias_step",
        "force": [6.0, 0.0, 0.0],
        "ramp": 0.5,
        "start": 6.4,
        "session_s": 9.0,
    },
    "session started resting on tissue (2 N up), lifted off at 5 s": {
        "contact": {"kind": "indentation", "start": -1.0, "duration": 6.0, "peak_force": 2.0, "ramp": 0.0},
        "start": 5.0,
    },
    "session started resting on tissue (2 N up), lifted off over 0.1 s at 5 s": {
        "contact": {"kind": "indentation", "start": -1.1, "duration": 6.2, "peak_force": 2.0, "ramp": 0.1},
        "start": 5.0,
    },
    "the same, the tool's mass stated (0.35 kg)": {
        "contact": {"kind": "indentation", "start": -1.1, "duration": 6.2, "peak_force": 2.0, "ramp": 0.1},
        "start": 5.0,
        "settings": {"haptic.tool_mass": 0.35},
    },
    "the same, on 4 N (more than the tool weighs), the robot's own wrench off": {
        "contact": {"kind": "indentation", "start": -1.1, "duration": 6.2, "peak_force": 4.0, "ramp": 0.1},
        "start": 5.0,
        "settings": {"kinematics.wrench_accuracy": 0.0},
    },
    "tool changed for one 0.5 kg heavier at 8.5 s (its centre of gravity 15 cm out)": {
        "contact": {"kind": "hanging_mass", "mass": 0.5, "start": 8.5, "point_S": [0.01, 0.0, 0.15]},
        "start": 8.5,
        "session_s": 15.0,
    },
    "the same, 0.2 kg heavier (2 cm off the axis)": {
        "contact": {"kind": "hanging_mass", "mass": 0.2, "start": 8.5, "point_S": [0.0, 0.02, 0.10]},
        "start": 8.5,
        "session_s": 15.0,
    },
}
"""The faults, each injected at ``FAULT_START_S`` into a ``DURATION_S`` session unless it says otherwise
(``start``, ``session_s``: the bias step lands in the demo's first contact, 6-7.5 s; the ramp needs 10 s; the
fast ramp during a contact is the second channel's row: the drift watch cannot judge in a contact).
A row with a ``contact`` adds it to the world instead, and is measured from its ``start``: the session starts
with the tool resting on tissue, straight up (a lighter tool to any estimator), lifted at ``start``; or a mass
hung on at ``start`` for good (a tool changed for a heavier one, its centre of gravity moved: the weight the
robot's own wrench and the sensor both see). One with ``settings`` runs with them (the clean run too)."""


def session(
    estimator: str, fault: dict[str, Any] | None, duration_s: float = DURATION_S
) -> tuple[np.ndarray, np.ndarray, list[dict], list, int]:
    """One demo session with ``fault`` injected (None: none): command times (s), forces, messages, events, and t0
    (ns)."""
    config, _ = load_config("demo")
    settings = {} if fault is None else fault.get("settings", {})
    config = apply_settings(
        config, {"session.realtime": False, "session.duration": duration_s, "estimator.name": estimator, **settings}
    )
    if fault is not None and "contact" in fault:
        config["world"]["contacts"] = [*config["world"].get("contacts", []), fault["contact"]]
    elif fault is not None and "kind" in fault:  # (``{"settings": ...}`` alone: a clean run with them)
        config["world"]["faults"] = [{"start": FAULT_START_S, **{k: v for k, v in fault.items() if k != "settings"}}]
    with tempfile.TemporaryDirectory() as folder:
        result = run_session(build_session(config), out=Path(folder) / "faults.mcap")
        rec = read_recording(result.path)
    t0 = result.events[0].t_ns
    commands = rec.topics["/haptic/command"][:-1]  # the session's final zero aside
    t = (np.array([t for t, _ in commands]) - t0) * 1e-9
    return t, np.array([m["force_D"] for _, m in commands]), [m for _, m in commands], result.events, t0


def made_up_force(force: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) ‖force − s·truth‖ minimised over s in [0, 1], per row, N: what no scaled-down true force explains."""
    tt = np.einsum("ij,ij->i", truth, truth)
    s = np.clip(np.einsum("ij,ij->i", force, truth) / np.where(tt > 0, tt, 1.0), 0.0, 1.0)
    return np.linalg.norm(force - s[:, None] * truth, axis=1)


def measure(estimator: str, clean, fault: dict[str, Any]) -> dict[str, Any]:
    """The made-up force, detection and zero times and the event of one fault against the clean run."""
    t_ref, force_ref, _, _, _ = clean
    fault = dict(fault)
    duration_s = fault.pop("session_s", DURATION_S)
    start_s = fault.get("start", FAULT_START_S)
    t, force, messages, events, t0 = session(estimator, fault, duration_s)
    n = min(len(t), len(t_ref))
    made_up = made_up_force(force[:n], force_ref[:n])
    after = t[:n] >= start_s
    faulty = np.array(
        [not m["enabled"] and m["reason"].split(" (")[0] not in WARMING_UP and m["reason"] != "" for m in messages[:n]]
    )
    detected = np.flatnonzero(after & faulty)
    t_detect = float(t[detected[0]]) if len(detected) else None
    end = start_s + min(fault.get("duration", np.inf), duration_s)
    # the fault's span, and until the force is back to zero or to the clean run's force
    back = np.flatnonzero((t[:n] >= end) & ((made_up < 0.05) | faulty))
    window = after & (t[:n] <= (t[back[0]] if len(back) else t[n - 1]))
    zeros = np.flatnonzero(after & (np.linalg.norm(force[:n], axis=1) == 0.0))
    event = next(
        (e for e in events if (e.t_ns - t0) * 1e-9 >= start_s and e.kind in ("fault", "bias_step", "weight_step")), None
    )
    period_s = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    return {
        "made_up_force_N": float(made_up[window].max()) if window.any() else 0.0,
        "over_half_newton_s": float(np.count_nonzero(made_up[window] > MADE_UP_BOUND_N)) * period_s,
        "detected_after_s": None if t_detect is None else t_detect - start_s,
        "zero_after_detection_s": None
        if t_detect is None or not len(zeros)
        else float(t[zeros[zeros >= detected[0]][0]]) - t_detect,
        "event": None if event is None else f"{event.kind}: {event.message}",
    }


def bench_faults(
    estimators: tuple[str, ...] = ("rls", "kalman"), progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Per estimator and fault: the numbers of the module docstring (JSON-ready)."""
    out: dict[str, Any] = {}
    for estimator in estimators:
        if progress:
            progress(f"{estimator}: clean run")
        clean: dict[tuple, Any] = {}  # by duration and settings
        out[estimator] = {}
        for label, fault in FAULTS.items():
            if progress:
                progress(f"{estimator}: {label}")
            duration_s = fault.get("session_s", DURATION_S)
            settings = fault.get("settings", {})
            key = (duration_s, *sorted(settings.items()))
            if key not in clean:
                clean[key] = session(estimator, {"settings": settings} if settings else None, duration_s)
            out[estimator][label] = measure(estimator, clean[key], fault)
    return out


COLUMNS = (
    "estimator",
    "fault",
    "made-up force (N)",
    "over 0.5 N for (ms)",
    "detected after (ms)",
    "zero after detection (ms)",
    "event",
)
"""The table's columns (``bench faults``'s printout and docs/results.md)."""


def table_rows(
    out: dict[str, Any], fmt: Callable[[Any, int], str], name: Callable[[str], str] = str
) -> list[tuple[tuple[str, ...], bool]]:
    """The rows of ``bench_faults``'s numbers under :data:`COLUMNS`, each with whether it ends an estimator's;
    numbers written with ``fmt(value, digits)``, estimators with ``name``."""

    def ms(value: float | None) -> str:
        return "never" if value is None else f"{1e3 * value:.0f}"

    rows: list[tuple[tuple[str, ...], bool]] = []
    for estimator, faults in out.items():
        for k, (label, r) in enumerate(faults.items()):
            row = (
                name(estimator) if k == 0 else "",
                label,
                fmt(r["made_up_force_N"], 2),
                ms(r.get("over_half_newton_s")),
                ms(r["detected_after_s"]),
                ms(r["zero_after_detection_s"]),
                r["event"] or "none",
            )
            rows.append((row, k == len(faults) - 1))
    return rows
