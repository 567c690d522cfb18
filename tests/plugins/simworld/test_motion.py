"""Motion scripts: smoothness, analytic derivatives against finite differences, determinism."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hapticlab.plugins.simworld.motion import (
    HORIZONTAL_R_BE,
    AxialRotation,
    Hold,
    MotionScript,
    RandomTour,
    StaticPoses,
    make_motion,
    quintic,
)


def vee(M: np.ndarray) -> np.ndarray:
    """The vector of the skew-symmetric part of (N, 3, 3) matrices."""
    return 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)


def fd_angular_velocity_E(script: MotionScript, t: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """ω of E in B, in E, from a central difference of R_BE: vee(R_BEᵀ Ṙ_BE)."""
    R = script.evaluate(t).R_BE
    R_dot = (script.evaluate(t + h).R_BE - script.evaluate(t - h).R_BE) / (2 * h)
    return vee(np.transpose(R, (0, 2, 1)) @ R_dot)


SCRIPTS = {
    "random_tour": lambda: RandomTour(seed=5, segment_s=1.0, dwell_s=0.3, max_translation=0.05),
    "static_poses": lambda: StaticPoses(seed=6, hold_s=0.5, move_s=1.2, max_translation=0.02),
    "axial_rotation": lambda: AxialRotation(speed_deg_s=72.0, turns=1.5, ramp_s=0.3, start_s=0.4),
    "hold": lambda: Hold(tilt_deg=20.0, roll_deg=45.0),
}


def test_quintic_derivatives_and_ends():
    tau = np.linspace(0.0, 1.0, 1001)
    s, ds, dds = quintic(tau)
    assert s[0] == 0.0 and s[-1] == 1.0
    assert ds[0] == ds[-1] == dds[0] == dds[-1] == 0.0
    h = 1e-6
    np.testing.assert_allclose(ds, (quintic(tau + h)[0] - quintic(tau - h)[0])[:] / (2 * h), atol=1e-6)
    inner = slice(1, -1)  # the clip at the ends makes one-sided there
    np.testing.assert_allclose(dds[inner], ((quintic(tau + h)[1] - quintic(tau - h)[1]) / (2 * h))[inner], atol=1e-5)
    assert np.isclose(ds.max(), 1.875)


@pytest.mark.parametrize("name", SCRIPTS)
def test_analytic_derivatives_match_finite_differences(name):
    script = SCRIPTS[name]()
    t = np.linspace(0.0, 6.0, 601) + 0.0037  # off the knots
    state = script.evaluate(t)
    np.testing.assert_allclose(state.w_BE_E, fd_angular_velocity_E(script, t), atol=1e-7)
    h = 1e-5
    alpha_fd = (script.evaluate(t + h).w_BE_E - script.evaluate(t - h).w_BE_E) / (2 * h)
    np.testing.assert_allclose(state.alpha_BE_E, alpha_fd, atol=1e-6)
    v_fd = (script.evaluate(t + h).p_BoEo_B - script.evaluate(t - h).p_BoEo_B) / (2 * h)
    np.testing.assert_allclose(state.v_BEo_B, v_fd, atol=1e-7)
    a_fd = (script.evaluate(t + h).v_BEo_B - script.evaluate(t - h).v_BEo_B) / (2 * h)
    np.testing.assert_allclose(state.a_BEo_B, a_fd, atol=1e-6)
    # rotations stay rotations
    R = state.R_BE
    np.testing.assert_allclose(np.transpose(R, (0, 2, 1)) @ R, np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


@pytest.mark.parametrize("name", SCRIPTS)
def test_scripts_are_c2_smooth(name):
    """No jumps in pose, angular velocity or acceleration anywhere, waypoints included."""
    script = SCRIPTS[name]()
    dt = 1e-4
    t = np.arange(-0.5, 8.0, dt)
    state = script.evaluate(t)
    R = state.R_BE
    step_angle = np.linalg.norm(Rotation.from_matrix(np.transpose(R[:-1], (0, 2, 1)) @ R[1:]).as_rotvec(), axis=1)
    w_max = np.linalg.norm(state.w_BE_E, axis=1).max()
    alpha_max = np.linalg.norm(state.alpha_BE_E, axis=1).max()
    assert step_angle.max() <= w_max * dt * 1.001 + 1e-12
    # a continuous acceleration moves by at most jerk·dt per step; a jump would be O(alpha_max)
    assert np.abs(np.diff(state.w_BE_E, axis=0)).max() <= alpha_max * dt * 1.001 + 1e-12
    assert np.abs(np.diff(state.alpha_BE_E, axis=0)).max() < 0.01 * max(alpha_max, 1e-9) + 1e-12
    assert np.abs(np.diff(state.a_BEo_B, axis=0)).max() < 0.01 * max(np.abs(state.a_BEo_B).max(), 1e-9) + 1e-12
    # at rest before t = 0
    assert np.all(state.w_BE_E[t < 0] == 0) and np.all(state.a_BEo_B[t < 0] == 0)


def test_constant_rate_rotation_has_exact_rate_and_no_acceleration():
    script = AxialRotation(speed_deg_s=30.0, turns=1, ramp_s=0.2)
    t = np.linspace(0.3, 11.5, 300)  # cruise: 0.2 s .. 11.8 s
    state = script.evaluate(t)
    np.testing.assert_allclose(state.w_BE_E, np.tile([0, 0, np.radians(30.0)], (300, 1)), atol=1e-15)
    assert np.all(state.alpha_BE_E == 0)
    np.testing.assert_allclose(fd_angular_velocity_E(script, t, h=1e-5), state.w_BE_E, atol=1e-9)


def test_axial_rotation_turns_and_stops():
    script = AxialRotation(speed_deg_s=45.0, turns=1, ramp_s=0.2, start_s=1.0)
    assert np.isclose(script.end_s, 1.0 + 8.0 + 0.2)  # 360/45 s plus one ramp's worth
    phi, phi_dot, _ = script.angle(np.array([0.0, 1.0, script.end_s, script.end_s + 5]))
    np.testing.assert_allclose(phi, [0.0, 0.0, 2 * np.pi, 2 * np.pi], atol=1e-12)
    np.testing.assert_allclose(phi_dot, 0.0, atol=1e-12)
    R_start, R_end = script.evaluate([0.0, script.end_s + 1.0]).R_BE
    np.testing.assert_allclose(R_end, R_start, atol=1e-12)
    # the tool axis (z of E) stays horizontal, along +x of B
    z_E_in_B = script.evaluate(np.linspace(0, 10, 50)).R_BE[:, :, 2]
    np.testing.assert_allclose(z_E_in_B, np.tile([1.0, 0.0, 0.0], (50, 1)), atol=1e-12)
    # smooth ramp: finite acceleration, peaking at 1.875·speed/ramp
    _, _, acc = script.angle(np.linspace(0, 10, 100_001))
    assert np.isclose(np.abs(acc).max(), 1.875 * np.radians(45.0) / 0.2, rtol=1e-4)
    by_duration = AxialRotation(speed_deg_s=-20.0, duration=5.0, ramp_s=0.5)
    np.testing.assert_allclose(by_duration.angle(100.0)[0], np.radians(-20.0) * 4.5)
    with pytest.raises(ValueError, match=r"^turns: give either duration or turns, not both$"):
        AxialRotation(duration=3.0, turns=1.0)
    with pytest.raises(ValueError, match=r"^ramp_s: must be <= 0.15 s: the rotation is too short"):
        AxialRotation(speed_deg_s=30, duration=0.3, ramp_s=0.2)


def test_random_tour_waypoints_stay_within_the_tilt_cone():
    tour = RandomTour(seed=3, max_tilt_deg=40.0, max_roll_deg=30.0)
    R_BE, _ = tour.waypoint_poses(300)
    tool_axis_B = R_BE[:, :, 2]
    tilt_deg = np.degrees(np.arccos(np.clip(-tool_axis_B[:, 2], -1, 1)))
    assert tilt_deg.max() <= 40.0 + 1e-9 and tilt_deg.max() > 35.0
    assert tilt_deg[0] == 0.0  # starts at the nominal pose
    # uniform over the cap: cos(tilt) uniform in [cos 40°, 1]
    assert abs(np.cos(np.radians(tilt_deg[1:])).mean() - (1 + np.cos(np.radians(40))) / 2) < 0.02
    # the moves pass exactly through the waypoints
    times = np.arange(1, 20) * tour.period_s
    np.testing.assert_allclose(tour.evaluate(times).R_BE, R_BE[1:20], atol=1e-12)


def test_random_tour_is_deterministic_and_order_independent():
    t = np.linspace(0, 300, 4000)  # more than one block of waypoints
    late_first = RandomTour(seed=12, max_translation=0.01)
    late = late_first.evaluate(t[::-1])
    fresh = RandomTour(seed=12, max_translation=0.01).evaluate(t)
    assert np.array_equal(late.R_BE[::-1], fresh.R_BE) and np.array_equal(late.p_BoEo_B[::-1], fresh.p_BoEo_B)
    other = RandomTour(seed=13, max_translation=0.01).evaluate(t)
    assert not np.allclose(other.R_BE, fresh.R_BE, atol=0.01)


def test_static_poses_hold_still_and_then_stop():
    script = StaticPoses(seed=4, hold_s=1.0, move_s=2.0, poses=5)
    mid = script.hold_midpoints(5)
    np.testing.assert_allclose(mid, [2.5, 5.5, 8.5, 11.5, 14.5])
    holds = script.evaluate(np.concatenate([mid - 0.45, mid + 0.45]))
    assert np.all(holds.w_BE_E == 0) and np.all(holds.alpha_BE_E == 0)
    np.testing.assert_allclose(holds.R_BE[:5], holds.R_BE[5:], atol=0)
    after = script.evaluate([15.0, 100.0, 1e5])
    np.testing.assert_allclose(after.R_BE, np.broadcast_to(script.waypoint_poses(6)[0][5], (3, 3, 3)), atol=1e-12)
    assert np.all(after.w_BE_E == 0)


def test_hold_tilts_the_tool_axis():
    script = Hold(tilt_deg=25.0, tilt_axis_B=(0.0, 2.0, 0.0), p_BoEo_B=(0.1, 0.2, 0.3))
    state = script.evaluate(np.array([0.0, 7.0]))
    tool_axis_B = state.R_BE[0, :, 2]
    assert np.isclose(np.degrees(np.arccos(-tool_axis_B[2])), 25.0)
    np.testing.assert_allclose(state.p_BoEo_B, [[0.1, 0.2, 0.3]] * 2)


def test_make_motion_by_name():
    assert isinstance(make_motion("indentation", tilt_deg=5.0), Hold)
    assert isinstance(make_motion("static_poses", poses=3), StaticPoses)
    with pytest.raises(ValueError, match=r"^script: must be 'random_tour', "):
        make_motion("wiggle")


def test_random_tour_orientation_is_the_geodesic_between_its_waypoints():
    """R_BE(t) = R_BE_a · Exp(s(t) u_E), built here with scipy from the waypoints."""
    tour = RandomTour(seed=7, segment_s=0.9, dwell_s=0.2, max_translation=0.04)
    t = np.linspace(-0.3, 250.0, 20_001)  # several waypoint blocks, holds included
    state = tour.evaluate(t)
    k = np.floor(np.maximum(t, 0.0) / tour.period_s).astype(int)
    R_wp, p_wp = tour.waypoint_poses(int(k.max()) + 2)
    s, _, _ = quintic((np.maximum(t, 0.0) - k * tour.period_s) / tour.segment_s)
    u_E = Rotation.from_matrix(np.transpose(R_wp[k], (0, 2, 1)) @ R_wp[k + 1]).as_rotvec()
    expected = R_wp[k] @ Rotation.from_rotvec(s[:, None] * u_E).as_matrix()
    np.testing.assert_allclose(state.R_BE, expected, rtol=0, atol=1e-14)
    np.testing.assert_allclose(state.p_BoEo_B, p_wp[k] + s[:, None] * (p_wp[k + 1] - p_wp[k]), rtol=0, atol=1e-15)


def test_axial_rotation_orientation_is_the_horizontal_pose_turned_about_z():
    script = AxialRotation(speed_deg_s=72.0, turns=1.5, ramp_s=0.3, start_s=0.4, roll0_deg=25.0)
    t = np.linspace(-1.0, 10.0, 5001)
    phi, _, _ = script.angle(t)
    expected = HORIZONTAL_R_BE @ Rotation.from_rotvec(np.outer(np.radians(25.0) + phi, [0.0, 0.0, 1.0])).as_matrix()
    np.testing.assert_allclose(script.evaluate(t).R_BE, expected, rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", SCRIPTS)
def test_one_time_at_a_time_gives_exactly_the_batch(name):
    """The live loop evaluates one or a few times per call: bit-for-bit the batch values."""
    t = np.linspace(-0.2, 6.0, 800)
    batch = SCRIPTS[name]().evaluate(t)
    script = SCRIPTS[name]()
    singles = [script.evaluate(time) for time in t[::-1]]  # in any order, scalars
    for field in ("R_BE", "p_BoEo_B", "w_BE_E", "alpha_BE_E", "v_BEo_B", "a_BEo_B"):
        joined = np.concatenate([getattr(state, field) for state in singles[::-1]])
        assert np.array_equal(joined, getattr(batch, field)), field
