"""A touch at a point of the tool gives a torque r × F: no twist about its own line, and a lever arm along the
tool; a sensor's force bias gives neither. The residuals here are that physics with the simulated sensor's
noise (0.12 N, 0.01 N·m per axis, seeded)."""

from __future__ import annotations

import numpy as np

from hapticlab.sessions.live.drift import BIN_NS
from hapticlab.sessions.live.lever import CLEAR_BINS, MIN_LEVER_M, LeverWatch

RATE_HZ = 1000.0
TIP_S = np.array([0.0, 0.0, 0.25])  # the demo tool's tip, m


def residual(seconds: float, force_S, point_S, bias_S=(0.0, 0.0, 0.0), seed: int = 0):
    """Stamps (ns), force (n, 3) N and torque (n, 3) N·m of a force ``force_S`` (N, (3,) or (n, 3)) acting at
    ``point_S`` (m) plus a force bias ``bias_S`` (no torque), with noise."""
    n = int(seconds * RATE_HZ)
    t_ns = (np.arange(n) * (1e9 / RATE_HZ)).astype(np.int64)
    force = np.broadcast_to(np.asarray(force_S, float), (n, 3))
    rng = np.random.default_rng(seed)
    torque = np.cross(np.asarray(point_S, float), force) + rng.normal(0.0, 0.01, (n, 3))
    return t_ns, force + np.asarray(bias_S) + rng.normal(0.0, 0.12, (n, 3)), torque


def watch_over(t_ns, force, torque, block: int = 3, judge: bool = True):
    """(stamp s, reason) after each block, fed in live-sized blocks."""
    watch, out = LeverWatch(), []
    for k in range(0, len(t_ns), block):
        watch.add(t_ns[k : k + block], force[k : k + block], torque[k : k + block], judge)
        out.append((t_ns[k] * 1e-9, watch.reason))
    return out


def test_touches_at_the_tip_in_any_direction_are_contacts():
    rng = np.random.default_rng(11)
    for seed in range(20):
        direction = rng.normal(size=3)
        force = (0.3 + 3.7 * rng.random()) * direction / np.linalg.norm(direction)
        found = watch_over(*residual(1.0, force, TIP_S, seed=seed))
        assert not any(r for _, r in found), (force, next(r for _, r in found if r))


def test_a_touch_on_the_shaft_beyond_the_adapter_is_a_contact():
    found = watch_over(*residual(1.0, [1.5, -0.5, 0.3], [0.0, 0.0, 2 * MIN_LEVER_M], seed=1))
    assert not any(r for _, r in found)


def test_a_force_bias_across_the_tool_is_held_from_its_first_bin():
    t_ns, force, torque = residual(1.0, [0.0, 0.0, 0.0], TIP_S, bias_S=[0.35, 0.0, 0.0], seed=2)
    found = watch_over(t_ns, force, torque)
    first = next(t for t, r in found if r)
    assert "acts where nothing touches the tool" in next(r for _, r in found if r)
    assert first <= 2 * BIN_NS * 1e-9 + 0.005  # the first full bin
    assert all(r for t, r in found if t > first)  # held while it stays


def test_a_drifting_bias_is_told_while_it_is_still_small():
    t_ns, force, torque = residual(2.0, [0.0, 0.0, 0.0], TIP_S, seed=3)
    force[:, 1] += 0.5 * t_ns * 1e-9  # 0.5 N/s: the bench's ramp
    found = watch_over(t_ns, force, torque)
    first = next(t for t, r in found if r)
    assert first <= 0.6  # the drift is then 0.3 N


def test_a_bias_beside_a_tip_contact_twists_the_residual():
    contact = np.array([1.5, 0.0, 2.5])  # 2.9 N, 31° off the tool's axis
    t_ns, force, torque = residual(1.0, contact, TIP_S, bias_S=[0.0, 0.9, 0.0], seed=4)
    reasons = [r for _, r in watch_over(t_ns, force, torque) if r]
    assert reasons and "twists about its own line" in reasons[0]


def test_a_push_along_the_tool_tells_nothing():
    found = watch_over(*residual(1.0, [0.0, 0.0, -3.0], TIP_S, seed=5))
    assert not any(r for _, r in found)


def test_nothing_is_judged_before_the_torque_stage_converged():
    t_ns, force, torque = residual(1.0, [0.0, 0.0, 0.0], TIP_S, bias_S=[1.0, 0.0, 0.0], seed=6)
    assert not any(r for _, r in watch_over(t_ns, force, torque, judge=False))


def test_a_hold_ends_only_after_clear_bins_a_touch_can_give():
    t_ns, force, torque = residual(1.0, [0.0, 0.0, 0.0], TIP_S, bias_S=[0.5, 0.0, 0.0], seed=7)
    t2, force2, torque2 = residual(1.0, [0.5, 0.0, 0.0], TIP_S, seed=8)  # then the same force at the tip
    found = watch_over(
        np.concatenate([t_ns, t2 + t_ns[-1] + 1_000_000]), np.vstack([force, force2]), np.vstack([torque, torque2])
    )
    held_last = max(t for t, r in found if r and t < 1.0 + 0.2)
    cleared = min(t for t, r in found if not r and t > 1.0)
    assert cleared > held_last
    # the first good bin closes within 20 ms of the switch; the hold ends as the CLEAR_BINS-th one closes
    assert (CLEAR_BINS - 1) * BIN_NS * 1e-9 + 0.005 < cleared - 1.0 < (CLEAR_BINS + 0.5) * BIN_NS * 1e-9


def test_unjudged_bins_keep_a_hold_and_reset_ends_it():
    """kalman's flag at the pose drops at each new pose: the bias held does not go with it."""
    t_ns, force, torque = residual(0.5, [0.0, 0.0, 0.0], TIP_S, bias_S=[0.5, 0.0, 0.0], seed=9)
    watch = LeverWatch()
    watch.add(t_ns, force, torque, True)
    assert watch.reason
    t2, force2, torque2 = residual(0.5, [0.0, 0.0, 0.0], TIP_S, seed=10)
    watch.add(t2 + t_ns[-1] + 1_000_000, force2, torque2, False)  # the residual gone, but nothing judged
    assert watch.reason
    watch.reset()
    assert not watch.reason


def test_the_lever_follows_the_stated_axis_and_a_zero_axis_reads_none():
    bias = residual(1.0, [0.0, 0.0, 0.0], TIP_S, bias_S=[0.0, 0.0, 0.5], seed=11)  # along S's z: across x
    tip_on_x = residual(1.0, [0.0, 0.0, 1.5], [0.25, 0.0, 0.0], seed=12)  # a tool along S's x, pushed across
    for axis, data, held in (((1, 0, 0), bias, True), ((1, 0, 0), tip_on_x, False), ((0, 0, 0), bias, False)):
        watch, reasons = LeverWatch(axis), []
        t_ns, force, torque = data
        for k in range(0, len(t_ns), 3):
            watch.add(t_ns[k : k + 3], force[k : k + 3], torque[k : k + 3], True)
            reasons.append(watch.reason)
        assert any(reasons) == held, (axis, held)
    assert LeverWatch((1e300, 0.0, 0.0)).a == [1.0, 0.0, 0.0]  # (no overflow into "no axis")
