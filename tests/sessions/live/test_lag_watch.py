"""The lag watch on a tool turning with poses τ late: it measures τ from the physics, ignores contacts,
and keeps its verdict while the tool stands still."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.frames import matrix_from_rotvec
from hapticlab.core.types import AlignedSamples
from hapticlab.sessions.live.watch import LagWatch

GRAVITY_FORCE_B = np.array([0.0, 0.0, -3.4])  # a 0.35 kg tool
BIAS_FORCE_S = np.array([0.4, -0.2, 0.1])
PARAMS = {"gravity_force_B": GRAVITY_FORCE_B.tolist(), "bias_force_S": BIAS_FORCE_S.tolist()}
RATE_HZ = 1000.0


def R_EB_at(t: np.ndarray, speed: float) -> np.ndarray:
    """(N, 3, 3): the flange turning about a tilted axis at ``speed`` rad/s."""
    axis = np.array([1.0, 0.4, 0.0]) / np.linalg.norm([1.0, 0.4, 0.0])
    return matrix_from_rotvec((speed * t)[:, None] * axis).transpose(0, 2, 1)


def blocks(
    lag_s: float,
    seconds: float,
    turning: bool = True,
    contact: tuple[float, float] | None = None,
    seed: int = 0,
    block: int = 7,
    start_s: float = 1.0,
):
    """The sensor sees the weight at the true pose; the poses handed with it are ``lag_s`` late."""
    rng = np.random.default_rng(seed)
    t = start_s + np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    speed = 1.5 if turning else 0.0
    true_R_EB = R_EB_at(t, speed)
    late_R_EB = R_EB_at(t - lag_s, speed)
    force_S = true_R_EB @ GRAVITY_FORCE_B + BIAS_FORCE_S + rng.normal(scale=0.12, size=(len(t), 3))
    if contact is not None:
        on = (t >= contact[0]) & (t < contact[1])
        force_S[on] += [0.0, 4.0, 0.0]  # beyond what a lag up to 0.5 s explains (0.5 s × 5.1 N/s)
    t_ns = (t * 1e9).astype(np.int64) + 10**12
    n = len(t)
    for i in range(0, n, block):
        s = slice(i, min(i + block, n))
        m = s.stop - s.start
        yield AlignedSamples(
            t_ns[s],
            force_S[s],
            np.zeros((m, 3)),
            late_R_EB[s],
            np.arange(m),
            np.zeros(m, int),
            np.zeros(m, bool),
            np.tile([1.0, 0, 0, 0], (m, 1)),
            None,
        )


@pytest.mark.parametrize("lag_s", [0.0, 0.02, 0.1, 0.2])
def test_the_lag_is_measured_from_the_turning_tool(lag_s):
    watch = LagWatch(max_turn_rate=10.0)
    for b in blocks(lag_s, 1.0):
        watch.add(b, PARAMS, None)
    assert watch.lag_s is not None
    # r ≈ τ·ġ holds to first order in τ·ω (0.3 rad at 200 ms: the estimate reads a little short then)
    assert abs(watch.lag_s - lag_s) < 0.005 + 0.1 * lag_s


def test_a_contact_is_not_read_as_a_lag():
    watch = LagWatch(max_turn_rate=10.0)
    for b in blocks(0.0, 2.0, contact=(0.5, 1.2)):
        watch.add(b, PARAMS, None)
        assert watch.lag_s is None or abs(watch.lag_s) < 0.01


def test_a_verdict_stands_while_the_tool_stands_still_and_a_reset_forgets_it():
    watch = LagWatch(max_turn_rate=10.0)
    for b in blocks(0.1, 1.0):
        watch.add(b, PARAMS, None)
    found = watch.lag_s
    assert found is not None and found > 0.08
    for b in blocks(0.1, 1.0, turning=False, seed=1, start_s=2.0):
        watch.add(b, PARAMS, None)
    assert watch.lag_s == pytest.approx(found, abs=1e-3)  # a still tool tells nothing: the verdict stands
    watch.reset()
    assert watch.lag_s is None


def test_one_sample_blocks_and_seven_sample_blocks_agree():
    """The sums do not depend on how the stream is cut into blocks (the loop reads 1 or 7 samples a tick)."""
    ones, sevens = LagWatch(max_turn_rate=10.0), LagWatch(max_turn_rate=10.0)
    for b in blocks(0.05, 0.8, block=1):
        ones.add(b, PARAMS, None)
    for b in blocks(0.05, 0.8, block=7):
        sevens.add(b, PARAMS, None)
    np.testing.assert_allclose(ones.sums, sevens.sums, rtol=1e-9)
    assert ones.lag_s == pytest.approx(sevens.lag_s, rel=1e-9)


def test_non_finite_parameters_for_a_while_do_not_blind_the_watch():
    """An estimator whose parameters are NaN for a block (a numerical corner) must not leave NaN in the sums:
    the lag of the poses that follow is still measured."""
    watch = LagWatch(max_turn_rate=10.0)
    stream = list(blocks(0.1, 1.0))
    nan_params = {"gravity_force_B": [np.nan, 0.0, -3.4], "bias_force_S": BIAS_FORCE_S.tolist()}
    for k, b in enumerate(stream):
        watch.add(b, nan_params if k == 20 else PARAMS, None)
    assert np.isfinite(watch.sums).all()
    assert watch.lag_s is not None and abs(watch.lag_s - 0.1) < 0.015


def test_a_non_finite_pose_is_a_jump_and_a_jump_across_it_is_still_seen():
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.watch import PoseWatch

    def pose(t_ms, angle, finite=True):
        q = np.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0])
        return PoseSample(t_ns=int(t_ms * 1e6), quat_BE=q if finite else q * np.nan, p_BoEo_B=np.zeros(3))

    watch = PoseWatch(50_000_000, max_turn_rate=10.0, max_speed=5.0)
    assert not watch.add([pose(0, 0.0), pose(2, 0.002)], now_ns=2_000_000)  # 1 rad/s: no jump
    assert watch.add([pose(4, 0.0, finite=False)], now_ns=4_000_000)
    assert watch.jump == (4_000_000, "a non-finite pose")
    # the next good pose is compared with the last good one (2 ms, 0.002 rad): 0.5 rad in 4 ms is a jump
    assert watch.add([pose(6, 0.5)], now_ns=6_000_000)
    assert watch.jump[0] == 6_000_000 and watch.jump[1].startswith("turned 0.498 rad in 4 ms")
