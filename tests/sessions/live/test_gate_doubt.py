"""The gate's doubt over a sudden step, tick by tick: what ends it (a contact that turns with the world, the
step gone, a weight step) and what must not (a world verdict while a contact was already there).

The gate is driven directly with one-sample blocks at 1 kHz from a tool turning at 1 rad/s about B's x; the
estimator's residual is given (seeded noise), acting at the tool's tip (its torque, for the lever watch), and
the raw reading is the residual (the step watch sees the step in it). The lag watch is left out: it has
tests of its own, and these residuals are contacts to it.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.sessions.live.gate import HapticGate

GRAVITY_B = np.array([0.0, 0.0, -3.4])  # the tool's weight in B, N
UP_B, SIDE_B = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
TIP_S = np.array([0.0, 0.0, 0.25])  # where the residual acts, m: the tool's tip (a contact, a load hung on it)


def run(residual_B, contact, seconds: float, seed: int = 0, reidentifies_weight=None):
    """Drive a gate for ``seconds``: ``residual_B(t)`` the estimator's residual in B, N, ``contact(t)`` its flag.
    Returns the events (t s, kind, message) and the reason at each tick."""
    gate = HapticGate("test", 0.1, None, None, 100_000_000, 500_000_000, 10.0, 5.0)
    gate.reidentifies_weight = reidentifies_weight
    gate.lag.add = lambda *args: None  # (see the module)
    rng, torque_rng = np.random.default_rng(seed), np.random.default_rng([seed, 1])  # (the force's noise as before)
    params = {"gravity_force_B": GRAVITY_B.tolist(), "bias_force_S": [0.0, 0.0, 0.0]}
    events, reasons = [], []
    for k in range(int(seconds * 1000)):
        t_ns = k * 1_000_000
        t = k * 1e-3
        R_EB = Rotation.from_rotvec([t, 0.0, 0.0]).as_matrix()
        residual_S = R_EB @ residual_B(t) + rng.normal(0.0, 0.12, 3)
        torque_S = np.cross(TIP_S, R_EB @ residual_B(t)) + torque_rng.normal(0.0, 0.01, 3)
        one = np.array([t_ns], dtype=np.int64)
        block = AlignedSamples(
            one,
            residual_S[None],
            np.zeros((1, 3)),
            R_EB[None],
            np.array([k]),
            np.zeros(1, dtype=np.int64),
            np.zeros(1, dtype=bool),
        )
        gate.on_samples(block, np.ones(1, dtype=bool), "", t_ns)
        est = Estimates(
            one,
            residual_S[None],
            torque_S[None],
            np.array([contact(t)]),
            np.ones(1, dtype=bool),
            np.ones(1, dtype=bool),
        )
        events += [(e.t_ns * 1e-9, e.kind, e.message) for e in gate.on_estimates(block, est, t_ns, params, None)]
        reasons.append(gate.reason(t_ns))
    return events, reasons


def test_a_sudden_contact_from_free_motion_is_felt_once_it_turns_with_the_world():
    events, reasons = run(lambda t: 2.0 * SIDE_B * (t >= 1.0), lambda t: t >= 1.0, 3.0)
    confirmed = [t for t, kind, _ in events if kind == "contact_confirmed"]
    assert reasons[1000].startswith("sudden force step (2.")
    assert len(confirmed) == 1 and 1.5 <= confirmed[0] < 1.6  # a full window after the step
    assert reasons[-1] == "" and not [k for _, k, _ in events if k in ("bias_step", "weight_step")]


def test_a_doubt_that_began_in_a_contact_ends_only_when_the_contact_has_gone():
    """A second sudden 2 N on top of a 3 N contact, both fixed in the world: the window holds both, so a world
    verdict says nothing of the step; the force stays off until the residual is gone for 0.1 s."""

    def residual_B(t):  # pressed in over 0.3 s, the second step at 1 s, all let go over 0.1 s from 2.5 s
        release = min(max((2.6 - t) / 0.1, 0.0), 1.0)
        return (3.0 * min(max((t - 0.2) / 0.3, 0.0), 1.0) + 2.0 * (t >= 1.0)) * release * SIDE_B

    events, reasons = run(residual_B, lambda t: 0.3 <= t < 2.58, 3.5, seed=1)
    assert not [k for _, k, _ in events if k in ("contact_confirmed", "bias_step", "weight_step")]
    held = [r.startswith("sudden force step") for r in reasons]
    assert all(held[1000:2550]) and not any(held[2750:])  # 0.1 s after a 20 ms mean of it is under 0.25 N


def test_a_sudden_pull_down_that_stays_is_a_weight_step_and_latches_without_a_weight_re_identification():
    events, reasons = run(lambda t: 2.0 * -UP_B * (t >= 1.0), lambda t: t >= 1.0, 3.0, seed=2)
    kinds = [k for _, k, _ in events]
    assert "weight_step" in kinds and "haptic_latched" in kinds and "contact_confirmed" not in kinds
    assert reasons[-1] == "weight step: re-arm needed"


def test_a_sudden_push_up_is_a_contact_not_a_weight_step():
    events, _ = run(lambda t: 2.0 * UP_B * (t >= 1.0), lambda t: t >= 1.0, 3.0, seed=3)
    kinds = [k for _, k, _ in events]
    assert "contact_confirmed" in kinds and "weight_step" not in kinds
