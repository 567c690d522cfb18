"""``kalman``'s torque bias re-opening: a torque-only refusal that lasts is a torque bias that moved.

A knock or a warm-up can move the torque bias without moving the force bias; the torque stage then refuses
every sample from there on as a "contact" (its random walk, 4e-4 N·m/√s, would take hours to widen its gate
over a 0.27 N·m step), so the recording is one long false contact and its contact torque is off by the step.
After ``torque_reopen_s`` of samples the force stage accepts and the torque stage refuses (and a torque larger
than any force within ``torque_reopen_lever`` of the sensor could make), the torque bias goes back to its
prior and is found again. Simulated physics, seeds 81-84 used nowhere else.
"""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.simworld import SimWorld
from hapticlab.plugins.simworld.contacts import Indentation
from hapticlab.sessions.bench.simulation import feed, simulate

RATE_HZ = 250.0
STEP_S = 12.0
STEP_TORQUE_S = np.array([0.2, -0.15, 0.1])  # N·m, in S: 0.27 N·m, ~27 times the simulated torque noise


def _stepped(seed: int, seconds: float = 30.0):
    block, _world = simulate(SimWorld(seed=seed, inertia=False), seconds, RATE_HZ)
    after = block.t_ns >= STEP_S * 1e9
    block.torque_S[after] += STEP_TORQUE_S  # the sensor's torque bias moves at STEP_S; the force is untouched
    return block, after


def _reopened(est: KalmanEstimator) -> list[float]:
    return [e.t_ns * 1e-9 for e in est.drain_events() if e.kind == "torque_bias_reopened"]


@pytest.mark.parametrize("seed", [81, 82])
def test_a_torque_bias_step_is_found_again_instead_of_refused_to_the_end(seed):
    block, _after = _stepped(seed)
    late = block.t_ns >= (STEP_S + 7.0) * 1e9  # 2 s after the re-opening is due
    fixed, never = KalmanEstimator(), KalmanEstimator(torque_reopen_s=0.0)
    out, _ = feed(fixed, block)
    old, _ = feed(never, block)
    times = _reopened(fixed)
    assert len(times) == 1 and STEP_S + 5.0 <= times[0] <= STEP_S + 5.5, times  # after 5 s of torque-only refusal
    assert _reopened(never) == []
    assert old.contact[late].mean() > 0.99  # without it: one false contact to the end
    assert out.contact[late].mean() < 0.01
    noise = 0.01  # N·m, the simulated sensor's torque noise per axis
    rms_fixed = np.sqrt((out.contact_torque_S[late] ** 2).mean(axis=0))
    rms_never = np.sqrt((old.contact_torque_S[late] ** 2).mean(axis=0))
    assert (rms_fixed < 1.3 * noise).all(), rms_fixed
    assert np.allclose(rms_never, np.abs(STEP_TORQUE_S), rtol=0.1), rms_never  # the step, taken for a contact
    assert np.array_equal(out.contact_force_S, old.contact_force_S)  # the force stage never sees the rule


@pytest.mark.parametrize("seed", [83, 84])
def test_contacts_do_not_reopen_the_torque_bias(seed):
    """A contact the force stage refuses ends the run; a light one (0.5 N, under the force gate at times)
    shorter than ``torque_reopen_s`` never reaches it; a force at the tool's tip (0.25 m) explains its torque."""
    contacts = [
        Indentation(start=6.0, duration=4.0, peak_force=0.5),
        Indentation(start=14.0, duration=10.0, peak_force=3.0),
    ]
    block, _ = simulate(SimWorld(seed=seed, inertia=False, contacts=contacts), 30.0, RATE_HZ)
    est = KalmanEstimator()
    out, _ = feed(est, block)
    assert _reopened(est) == []
    in_contact = (block.t_ns >= 15e9) & (block.t_ns <= 23e9)
    assert out.contact[in_contact].mean() > 0.95  # the long contact stays one


@pytest.mark.parametrize("size", [1, 7])
def test_the_compiled_cascade_and_the_numpy_reference_reopen_at_the_same_sample(size, numpy_reference):
    block, _ = _stepped(81, 20.0)
    fast, ref = KalmanEstimator(), KalmanEstimator(kernel=numpy_reference)
    a = [fast.update_block(block.subset(slice(i, i + size))) for i in range(0, len(block), size)]
    b = [ref.update_block(block.subset(slice(i, i + size))) for i in range(0, len(block), size)]
    t_fast, t_ref = _reopened(fast), _reopened(ref)
    assert len(t_fast) == 1 and t_fast == t_ref
    for key in ("contact", "converged_force", "converged_torque"):
        assert np.array_equal(
            np.concatenate([getattr(p, key) for p in a]), np.concatenate([getattr(p, key) for p in b])
        ), key
    assert np.allclose(fast.torque.P, ref.torque.P, rtol=1e-6, atol=1e-12)
    assert np.allclose(fast.torque.x, ref.torque.x, rtol=1e-6, atol=1e-9)


def test_the_options_are_validated():
    for key, value in (("torque_reopen_s", -1.0), ("torque_reopen_s", float("nan")), ("torque_reopen_lever", -0.1)):
        with pytest.raises(ValueError, match=key):
            KalmanEstimator(**{key: value})
