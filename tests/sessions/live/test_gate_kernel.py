"""The live loop's compiled screen (``sessions/live/gate_kernel.py``) against the numpy masks and reason it
replaces (``AlignedSamples.usable``, ``implausible``, ``data_reason``), on the simulated tour the estimators'
kernels are held to (``kernel_tour``, tests/helpers.py), spoilt at random."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import kernel_tour


@pytest.fixture(scope="module")
def sim():
    return kernel_tour(3.0)


class _Range:
    """A sensor's range (HasRange), N and N·m."""

    range_force_S = np.array([40.0, 40.0, 120.0])
    range_torque_S = np.array([2.0, 2.0, 2.5])


def _spoilt(block, rng, size: int):
    """``size`` consecutive samples of the tour with faults a real stream has, each in some blocks: NaN and inf
    in the wrench, orientation and position, stale orientations, bad status words, readings beyond the range
    (with a good status and with a bad one)."""
    from dataclasses import replace

    start = int(rng.integers(0, len(block) - size))
    b = block.subset(slice(start, start + size))
    b = replace(
        b,
        force_S=b.force_S.copy(),
        torque_S=b.torque_S.copy(),
        R_EB=b.R_EB.copy(),
        stale=b.stale.copy(),
        status=b.status.copy(),
        p_BoEo_B=None if rng.random() < 0.3 else rng.normal(0.0, 0.3, (size, 3)),
    )
    for _ in range(int(rng.integers(0, 3))):
        i, k = int(rng.integers(size)), int(rng.integers(3))
        fault = int(rng.integers(7))
        if fault == 0:
            b.force_S[i, k] = rng.choice([np.nan, np.inf, -np.inf])
        elif fault == 1:
            b.torque_S[i, k] = rng.choice([np.nan, np.inf])
        elif fault == 2:
            b.R_EB[i, k, int(rng.integers(3))] = np.nan
        elif fault == 3 and b.p_BoEo_B is not None:
            b.p_BoEo_B[i, k] = np.inf
        elif fault == 4:
            b.stale[i] = True
        elif fault == 5:
            b.status[i] = int(rng.choice([1, 2, 1 << 16]))
        else:
            (b.force_S if rng.random() < 0.5 else b.torque_S)[i, k] = rng.choice([-1.0, 1.0]) * 500.0
    return b


@pytest.mark.parametrize("size", [1, 7, 64])
def test_screen_kernel_gives_the_reference_s_masks_and_reason(sim, size):
    """The live loop's compiled screen against ``AlignedSamples.usable``, ``implausible`` and ``data_reason``, on
    blocks of the tour spoilt at random (seeded): the same masks and the same reason, with and without a range."""
    from hapticlab.sessions.live.screen import data_reason, implausible, screen

    rng = np.random.default_rng(size)
    reasons = set()
    for _ in range(400):
        block = _spoilt(sim, rng, size)
        for sensor in (_Range(), None):
            beyond = implausible(block, sensor)
            usable = block.usable & ~beyond
            reason = data_reason(block, usable, beyond)
            got = screen(block, sensor)
            assert np.array_equal(got[0], usable) and np.array_equal(got[1], beyond) and got[2] == reason
            reasons.add(reason)
    assert reasons == {
        "",
        "implausible sensor reading (beyond its range)",
        "stale kinematics",
        "sensor saturated or in error",
        "non-finite sensor reading",
    }  # every branch was taken
