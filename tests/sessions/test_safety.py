"""The force governor: zero on doubt, clamp, rate limit."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.plugins import ConfigError
from hapticlab.sessions.config import HapticSettings
from hapticlab.sessions.live.safety import ForceGovernor

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


@pytest.mark.parametrize("kw, key", [({"max_force": -1.0}, "haptic.max_force"),
                                     ({"max_force_rate": float("inf")}, "haptic.max_force_rate"),
                                     ({"ready_force_std": 0.0}, "haptic.ready_force_std")])
def test_bad_limits_are_refused(kw, key):
    with pytest.raises(ConfigError, match=f"^{key}: must be"):
        HapticSettings(**kw)
