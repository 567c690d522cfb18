"""The force governor: zero on doubt, clamp, rate limit."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hapticlab.core.host.registry import ConfigError
from hapticlab.sessions.live.safety import ForceGovernor
from hapticlab.sessions.settings import HapticSettings

I3 = np.eye(3)


def governor(**kw):
    return ForceGovernor(HapticSettings(**kw), period_s=1e-3)


def test_clamp_keeps_the_direction():
    g = governor(max_force=4.0, max_force_rate=1e9)
    cmd = g.command(0, np.array([6.0, 8.0, 0.0]), I3)
    assert cmd.enabled and np.allclose(cmd.force_D, [2.4, 3.2, 0.0])


def test_rate_limit_and_immediate_zero():
    g = governor(max_force=10.0, max_force_rate=100.0)  # 0.1 N per 1 ms period
    forces = [g.command(k, np.array([0.0, 0.0, 5.0]), I3).force_D[2] for k in range(5)]
    assert np.allclose(forces, [0.1, 0.2, 0.3, 0.4, 0.5])
    off = g.command(5, np.array([0.0, 0.0, 5.0]), I3, reason="stale kinematics")
    assert not off.enabled and off.reason == "stale kinematics" and np.all(off.force_D == 0)
    assert g.command(6, np.array([0.0, 0.0, 5.0]), I3).force_D[2] == pytest.approx(0.1)  # ramps again


def test_non_finite_or_missing_estimate_gives_zero():
    g = governor()
    nan = g.command(0, np.array([np.nan, 0.0, 0.0]), I3)
    assert not nan.enabled and nan.reason == "non-finite contact force" and np.all(nan.force_D == 0)
    none = g.command(1, None, None)
    assert not none.enabled and none.reason == "no estimate yet"


def test_mapping_into_the_device_frame():
    # R_DB: a quarter turn about z; R_BE: a half turn about x
    g = governor(max_force=10.0, max_force_rate=1e9, rotation_DB=(0.0, 0.0, np.pi / 2), scale=0.5)
    R_BE = np.diag([1.0, -1.0, -1.0])
    cmd = g.command(0, np.array([2.0, 0.0, 4.0]), R_BE)
    # f_B = (2, 0, -4); f_D = Rz(90°) f_B = (0, 2, -4); scaled by 0.5
    assert np.allclose(cmd.force_D, [0.0, 1.0, -2.0])


@pytest.mark.parametrize(
    ("kw", "key"),
    [
        ({"max_force": -1.0}, "haptic.max_force"),
        ({"max_force_rate": float("inf")}, "haptic.max_force_rate"),
        ({"ready_force_std": 0.0}, "haptic.ready_force_std"),
    ],
)
def test_bad_limits_are_refused(kw, key):
    with pytest.raises(ConfigError, match=f"^{key}: must be"):
        HapticSettings(**kw)


# ---------------------------------------------------------------- the mapping: deadband, low-pass, clamp, slew


def test_deadband_is_continuous_and_keeps_the_direction():
    g = governor(max_force=10.0, max_force_rate=1e9, deadband=0.5)
    direction = np.array([0.6, 0.0, 0.8])
    magnitudes = np.linspace(0.0, 2.0, 2001)  # 1 mN apart, across the edge at 0.5 N
    out = np.array([g.command(k, m * direction, I3).force_D for k, m in enumerate(magnitudes)])
    norms = np.linalg.norm(out, axis=1)
    assert np.all(norms[magnitudes <= 0.5] == 0.0)
    assert np.allclose(norms, np.maximum(magnitudes - 0.5, 0.0), atol=1e-12)  # magnitude less the deadband
    assert np.max(np.abs(np.diff(norms))) <= 1e-3 + 1e-12  # no step anywhere: at most the input's own change
    assert np.allclose(out[-1] / norms[-1], direction)
    assert g.command(9999, 0.3 * direction, I3).enabled  # below the deadband: on, at zero, not "off"


@pytest.mark.parametrize("cutoff_hz", [1.0 / (2 * np.pi * 0.010), 10.0])  # τ = 10 ms (10 periods); τ = 15.9 ms
def test_low_pass_step_response_reaches_63_percent_at_one_time_constant(cutoff_hz):
    period = 1e-3
    g = ForceGovernor(HapticSettings(max_force=10.0, max_force_rate=1e9, cutoff_hz=cutoff_hz), period_s=period)
    y = np.array([g.command(k, np.array([0.0, 2.0, 0.0]), I3).force_D[1] / 2.0 for k in range(1, 200)])
    tau = 1.0 / (2 * np.pi * cutoff_hz)
    n = tau / period  # y[k-1] is the response after k periods
    before, after = y[int(np.floor(n)) - 1], y[int(np.ceil(n)) - 1]
    assert before <= 1 - np.exp(-1) + 1e-12 <= after + 2e-12
    assert after - before <= 1 - np.exp(-period / tau) + 1e-12  # within one period's discretisation
    assert y[0] == pytest.approx(1 - np.exp(-period / tau))  # exact: 1 − e^(−T/τ) after one period
    assert y[-1] == pytest.approx(1.0, abs=1e-4) and np.all(np.diff(y) > 0)  # no overshoot


def test_zero_for_a_reason_empties_the_filter():
    g = governor(max_force=10.0, max_force_rate=1e9, cutoff_hz=5.0)
    for k in range(300):  # the filter settles at 3 N
        settled = g.command(k, np.array([3.0, 0.0, 0.0]), I3).force_D[0]
    assert settled == pytest.approx(3.0, rel=1e-3)
    assert not g.command(300, np.array([3.0, 0.0, 0.0]), I3, reason="stale kinematics").enabled
    back = g.command(301, np.array([0.0, 0.0, 0.0]), I3)  # a re-enable with no force must not replay the 3 N
    assert back.enabled and np.array_equal(back.force_D, np.zeros(3))
    first = g.command(302, np.array([3.0, 0.0, 0.0]), I3).force_D[0]
    assert first == pytest.approx(3.0 * (1 - np.exp(-2 * np.pi * 5.0 * 1e-3)))  # from zero, not from 3 N


def test_clamp_to_the_device_limit_keeps_the_direction():
    g = governor(max_force=4.0, max_force_rate=1e9)
    g.device_max_force = 2.5
    cmd = g.command(0, np.array([0.0, -6.0, 8.0]), I3)
    assert np.allclose(cmd.force_D, [0.0, -1.5, 2.0])  # 2.5 N along (0, −0.6, 0.8)
    g.device_max_force = 9.0  # the session's max_force is then the smaller
    assert np.linalg.norm(g.command(1, np.array([0.0, -6.0, 8.0]), I3).force_D) == pytest.approx(4.0)
    for unusable in (float("nan"), 0.0, -1.0, float("inf")):
        g.device_max_force = unusable
        cmd = g.command(2, np.array([1.0, 0.0, 0.0]), I3)
        assert not cmd.enabled and np.array_equal(cmd.force_D, np.zeros(3))
        assert cmd.reason.startswith("haptic device reports no usable force limit")


def test_a_device_limit_that_falls_below_the_command_brings_the_force_down_at_once():
    """The device lowers its maximum (e.g. it reports a hot motor) while 4 N are on the hand: the next
    command is at the new limit, still on, not zeroed as 'out of bounds' and not slewed down slowly."""
    g = governor(max_force=5.0, max_force_rate=100.0)  # 0.1 N a period
    for k in range(100):
        on = g.command(k, np.array([4.0, 0.0, 0.0]), I3)
    assert on.enabled and on.force_D[0] == pytest.approx(4.0)
    g.device_max_force = 1.5
    lowered = g.command(100, np.array([4.0, 0.0, 0.0]), I3)
    assert lowered.enabled and lowered.reason == ""
    assert np.allclose(lowered.force_D, [1.5, 0.0, 0.0])


def test_the_order_is_map_deadband_lowpass_clamp_slew():
    # a quarter turn about z, scale 2: (1.5, 0, 0) in S → (0, 3, 0) in D; deadband 1 N → 2 N; clamp 1.5 N; slew 0.1 N
    g = governor(max_force=1.5, max_force_rate=100.0, scale=2.0, rotation_DB=(0.0, 0.0, np.pi / 2), deadband=1.0)
    forces = np.array([g.command(k, np.array([1.5, 0.0, 0.0]), I3).force_D for k in range(20)])
    assert np.allclose(forces[:, 0], 0.0) and np.allclose(forces[:, 2], 0.0)
    assert np.allclose(forces[:5, 1], [0.1, 0.2, 0.3, 0.4, 0.5]) and forces[-1, 1] == pytest.approx(1.5)


@pytest.mark.parametrize(
    ("kw", "key"),
    [
        ({"deadband": -0.1}, "haptic.deadband"),
        ({"cutoff_hz": float("nan")}, "haptic.cutoff_hz"),
        ({"cutoff_hz": -1.0}, "haptic.cutoff_hz"),
        ({"rearm_button": 64}, "haptic.rearm_button"),
        ({"rearm_button": True}, "haptic.rearm_button"),
    ],
)
def test_bad_mapping_settings_are_refused(kw, key):
    with pytest.raises(ConfigError, match=f"^{key}: must be"):
        HapticSettings(**kw)


def test_the_gate_counts_flag_flips_across_blocks_and_keeps_when_the_flag_went_down():
    """What the session summary reports (``convergence_flag_flips``) and what "estimator no longer converged"
    waits on: flips counted within and across blocks of any size, the first convergence an event at its sample,
    and the time the force stage's flag has been down since."""
    from hapticlab.core.types import Estimates
    from hapticlab.sessions.live.gate import HapticGate

    gate = HapticGate("rls", 0.1, None, None, 100_000_000, 500_000_000, 3.0, 1.0)
    t0 = 0
    events = []
    for force, torque in (([0, 0, 1], [0, 0, 0]), ([1, 0], [0, 1]), ([0], [1]), ([0, 0, 1, 1, 0, 1, 0], [1] * 7)):
        m = len(force)
        t = np.arange(t0, t0 + m, dtype=np.int64) * 1_000_000
        est = Estimates(
            t,
            np.zeros((m, 3)),
            np.zeros((m, 3)),
            np.zeros(m, dtype=bool),
            np.array(force, dtype=bool),
            np.array(torque, dtype=bool),
        )
        block = SimpleNamespace(t_ns=t, R_EB=np.repeat(np.eye(3)[None], m, axis=0))  # (the drift watch's part)
        events += gate.on_estimates(block, est, int(t[-1]))
        t0 += m
    # force: 0 0 1 | 1 0 | 0 | 0 0 1 1 0 1 0 -> up at 2, down at 4, up at 8, down at 10, up at 11, down at 12
    assert gate.flips == [6, 1] and gate.converged == [False, True]
    assert gate.flags.down_since_ns == 12_000_000  # the trailing run of samples with the flag down began at sample 12
    assert [(e.t_ns, e.message) for e in events if e.kind == "converged"] == [
        (2_000_000, "rls force stage converged"),
        (4_000_000, "rls torque stage converged"),
    ]
