"""``hapticlab bench estimators``: the estimator family's targets, measured in simulation.

Each scenario runs the paper's ``rls`` (where it applies) beside ``kalman`` with
and without the option under test, on one seeded simulated world at 1 kHz with
the default sensor (0.12 N, 0.01 N·m per axis), and reports the numbers the
family's targets name:

* ``mount``: a 5° sensor mount rotation, 30 s random tour: the angle between
  the estimated and the true R_SE, and RMS / noise over the last 15 s;
* ``inertia_tour``: the tool's own inertial force on a random tour that turns
  (ω up to 2 rad/s, ω̇ up to 4.4 rad/s²) and moves the flange up to 0.1 m per
  axis, RMS / noise with and without ``inertia``;
* ``rotation_104g``: the paper's 104 g test at 72 deg/s at ¼ of Table I's noise,
  Max AE of |contact force| per sample and over a 10 ms moving mean;
* ``time_lag``: kinematics 20 ms late, RMS / noise with and without ``time_lag_s``;
* ``gain``: a 2 % symmetric force calibration error, with and without ``gain_force_S``;
* ``payload``: 100 g hung at 20 s during a 30 s tour with 0.5 N/min drift:
  when the change is recognised, when each stage's flag is up again.

The drift scenarios (0.5 N/min, with and without indentations) are in ``bench
paper`` (``drift_contact``) and in the tests; the speed per option in
``bench/speed.py``. Numbers are machine-independent (seeded simulation).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2, quat_wxyz_from_matrix, rotvec_from_matrix
from hapticlab.core.host.registry import Registry
from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.bench.paper import estimator_factory, rotation_test
from hapticlab.sessions.bench.paper_setup import LOW_NOISE, REFERENCE_MASS_KG, PaperSetup
from hapticlab.sessions.bench.simulation import feed, simulate
from hapticlab.sessions.offline.metrics import max_ae, rms

RATE_HZ = 1000.0
NOISE_FORCE = 0.12
"""The default simulated sensor's force noise per axis, N."""
MOUNT_ROTATION_SE = (np.deg2rad(5.0) * np.array([0.6, -0.5, 0.62]) / np.linalg.norm([0.6, -0.5, 0.62])).tolist()
"""A 5° mount rotation about an axis off every sensor axis, rad."""
GAIN_FORCE_S = [[0.02, 0.01, 0.0], [0.01, -0.015, 0.005], [0.0, 0.005, 0.01]]
"""A symmetric force calibration error of up to 2 %."""
KINEMATICS_LAG_S = 0.02
BASE_MODEL = "kalman bias_force_tilt_rw=0"
"""The row of ``kalman`` without its learnt tilt walk (on by default): the paper's base model
alone, the gap each option is there to close. The defaults' row ("kalman") follows part of it with the walk."""


def base_model() -> KalmanEstimator:
    """``kalman`` with the tilt walk off (``BASE_MODEL``)."""
    return KalmanEstimator(bias_force_tilt_rw=0.0)


def tour(seconds: float = 30.0, seed: int = 3, **world: Any) -> tuple[SimWorld, AlignedSamples]:
    """A random tour of the default world (tool inertia on) with ``world`` table overrides.

    The block carries what the kinematics report (a late stream's poses when the world
    has ``robot.kinematics_lag``), with quaternions and positions.
    """
    w = SimWorld.from_config({"seed": seed, "motion": {"script": "random_tour"}, **world})
    block, _ = simulate(w, seconds, RATE_HZ)
    R_BE, p_BoEo_B = w.pose(block.t_ns * 1e-9)
    block = AlignedSamples(
        block.t_ns,
        block.force_S,
        block.torque_S,
        R_BE.transpose(0, 2, 1),
        block.seq,
        block.status,
        block.stale,
        quat_wxyz_from_matrix(R_BE),
        p_BoEo_B,
    )
    return w, block


def rms_after(out: Estimates, block: AlignedSamples, after_s: float) -> np.ndarray:
    """(3,) RMS of the contact force over the samples after ``after_s``, N."""
    return rms(out.contact_force_S[block.t_ns * 1e-9 >= after_s])


def angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The angle between two rotations, degrees."""
    return float(np.rad2deg(np.linalg.norm(rotvec_from_matrix(R_a.T @ R_b))))


def compare(
    block: AlignedSamples, after_s: float, variants: dict[str, Callable[[], Any]], chunk: int = 7
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Run each estimator variant over the block; (RMS / noise per variant, the estimators)."""
    rows, built = {}, {}
    for name, make in variants.items():
        est = make()
        out, _ = feed(est, block, chunk=chunk)
        rows[name] = (rms_after(out, block, after_s) / NOISE_FORCE).tolist()
        built[name] = est
    return rows, built


def mount() -> dict[str, Any]:
    """5° mount rotation: how well ``mount_rotation = true`` finds it, and what it does to the RMS."""
    world, block = tour(30.0, sensor={"mount_rotation": MOUNT_ROTATION_SE})
    rows, built = compare(
        block,
        15.0,
        {
            "rls": RLSEstimator,
            "kalman": KalmanEstimator,
            BASE_MODEL: base_model,
            "kalman mount_rotation": lambda: KalmanEstimator(mount_rotation=True),
        },
    )
    return {
        "rms_over_noise_last_15s": rows,
        "mount_error_deg": angle_deg(world.R_SE, built["kalman mount_rotation"].R_SE),
    }


TRANSLATION_M = 0.1
"""The inertia tour also moves the flange up to this far per axis (m), so linear acceleration counts."""


def inertia_tour() -> dict[str, Any]:
    """The tool's inertial force on a lively tour that turns and translates, with and without ``inertia = true``."""
    world, block = tour(30.0, seed=4, motion={"script": "random_tour", "max_translation": TRANSLATION_M})
    rows, _ = compare(
        block,
        15.0,
        {
            "rls": RLSEstimator,
            "kalman": KalmanEstimator,
            BASE_MODEL: base_model,
            "kalman inertia": lambda: KalmanEstimator(inertia=True),
        },
    )
    w = world.wrench(block.t_ns[block.t_ns >= 15e9] * 1e-9)
    return {"rms_over_noise_last_15s": rows, "inertial_force_rms_N": rms(w["inertial_force_S"]).tolist()}


def rotation_104g(speed: float = 72.0) -> dict[str, Any]:
    """The paper's rotation test at ``speed`` deg/s, ¼ of Table I's noise; the 104 g mass is a load."""
    setup, noise = PaperSetup(), LOW_NOISE
    load = REFERENCE_MASS_KG * GRAVITY_M_S2
    variants = {
        "rls": estimator_factory(Registry(), "rls", setup),  # as in bench paper
        "kalman": lambda: KalmanEstimator(payload_change_s=0, **noise),
        "kalman inertia": lambda: KalmanEstimator(inertia=True, payload_change_s=0, **noise),
    }
    out = {}
    for name, make in variants.items():
        numbers, _, magnitude = rotation_test(setup, make, speed, noise)
        smoothed = np.convolve(magnitude, np.ones(10) / 10, mode="valid") - load
        out[name] = {
            "max_ae": numbers["max_ae"],
            "max_ae_10ms": float(max_ae(smoothed)),
            "mae": numbers["mae"],
            "contact_detected_pct": numbers["contact_detected_pct"],
        }
    return {"speed_deg_s": speed, "noise_force": noise["noise_force"], "estimators": out}


def time_lag() -> dict[str, Any]:
    """Kinematics 20 ms late, with and without ``time_lag_s``."""
    _, block = tour(20.0, seed=5, robot={"kinematics_lag": KINEMATICS_LAG_S}, inertia=False)
    rows, _ = compare(
        block,
        10.0,
        {
            "kalman": KalmanEstimator,
            BASE_MODEL: base_model,
            "kalman time_lag_s": lambda: KalmanEstimator(time_lag_s=KINEMATICS_LAG_S),
        },
    )
    return {"lag_s": KINEMATICS_LAG_S, "rms_over_noise_last_10s": rows}


def gain() -> dict[str, Any]:
    """A 2 % force calibration error, with and without ``gain_force_S``."""
    _, block = tour(20.0, seed=6, sensor={"gain_force": GAIN_FORCE_S}, inertia=False)
    rows, _ = compare(
        block,
        10.0,
        {
            "kalman": KalmanEstimator,
            BASE_MODEL: base_model,
            "kalman gain_force_S": lambda: KalmanEstimator(gain_force_S=GAIN_FORCE_S),
        },
        chunk=64,
    )
    return {"gain_force_S": GAIN_FORCE_S, "rms_over_noise_last_10s": rows}


def payload(start_s: float = 20.0) -> dict[str, Any]:
    """100 g hung for good at ``start_s`` during a tour with 0.5 N/min drift (the payload tests' world)."""
    setup = PaperSetup(mass=0.2)
    world = setup.world(
        {"script": "random_tour", "max_tilt_deg": 60.0, "segment_s": 3.0},
        [{"kind": "hanging_mass", "start": start_s, "duration": 1e9, "mass": 0.1}],
        noise_force=0.12,
        noise_torque=0.01,
        drift_force=[0.5 / 60.0 / np.sqrt(2), 0.5 / 60.0 / np.sqrt(2), 0.0],
    )
    block, _ = simulate(world, start_s + 10.0, RATE_HZ)
    est = KalmanEstimator()
    out, _ = feed(est, block, chunk=64)
    events = [e for e in est.drain_events() if e.kind == "payload_change"]  # (not the identification's events)
    if not events:
        return {"recognised_after_s": None}
    t_event = events[0].t_ns
    hung_ns = int(block.t_ns[0] + start_s * 1e9)
    return {
        "recognised_after_s": (t_event - hung_ns) * 1e-9,
        "force_flag_up_after_hang_s": up_after(block, out.converged_force, hung_ns),
        "torque_flag_up_after_event_s": up_after(block, out.converged_force & out.converged_torque, t_event),
        "contact_after_event_pct": 100.0 * float(np.mean(out.contact[block.t_ns > t_event])),
        "event": events[0].message,
    }


def up_after(block: AlignedSamples, flags: np.ndarray, t_ns: int) -> float | None:
    """Seconds after t_ns until ``flags`` are up and stay up; None if they end down."""
    after = np.flatnonzero(block.t_ns > t_ns)
    up = flags[after]
    if not up[-1]:
        return None
    down = np.flatnonzero(~up)
    return 0.0 if len(down) == 0 else (int(down[-1]) + 1) / RATE_HZ


SCENARIOS: dict[str, Callable[[], dict[str, Any]]] = {
    "mount": mount,
    "inertia_tour": inertia_tour,
    "rotation_104g": rotation_104g,
    "time_lag": time_lag,
    "gain": gain,
    "payload": payload,
}


def bench_estimators(progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Every scenario's numbers (JSON-ready)."""
    out = {}
    for name, scenario in SCENARIOS.items():
        if progress:
            progress(name)
        out[name] = scenario()
    return out
