"""The simulated world's physics, randomness and configuration.

Expected values are computed here independently (scipy rotations, finite
differences of positions and angular momentum), never copied from the code.
"""

from __future__ import annotations

import itertools
import tomllib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hapticlab.core.host.registry import ConfigError
from hapticlab.core.types import STATUS_SATURATED
from hapticlab.plugins.simworld import (
    AxialRotation,
    HangingMass,
    Hold,
    Indentation,
    RandomTour,
    RobotParams,
    SensorParams,
    SimWorld,
    ToolParams,
)
from hapticlab.plugins.simworld.clock import SampleClock
from hapticlab.plugins.simworld.randomness import gaussian_noise

G = 9.80665


def rotation_SG(world: SimWorld, R_BE: np.ndarray, mount_rotvec, tilt_rotvec) -> np.ndarray:
    """R_SG = R_SE R_EB R_BG built from the rotation vectors with scipy (independent of the world)."""
    R_SE = Rotation.from_rotvec(mount_rotvec).as_matrix()
    R_BG = Rotation.from_rotvec(tilt_rotvec).as_matrix()
    return R_SE @ np.transpose(R_BE, (0, 2, 1)) @ R_BG


def vee(M: np.ndarray) -> np.ndarray:
    """The vector of the skew-symmetric part of (N, 3, 3) matrices."""
    return 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)


# --------------------------------------------------------------------------- static model


@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0), (0.05, -0.08, 0.3)])
def test_static_reading_is_weight_in_S_plus_bias(mount):
    tilt = (0.03, -0.02, 0.01)
    world = SimWorld(
        sensor=SensorParams(mount_rotation_SE=mount),
        robot=RobotParams(base_tilt_BG=tilt),
        motion=RandomTour(seed=3, dwell_s=0.5),
        seed=3,
        inertia=False,
    )
    t = np.linspace(0.0, 20.0, 333)
    reading = world.wrench(t, noise=False)
    R_BE, _ = world.pose(t)
    m = world.tool.mass
    weight_S = rotation_SG(world, R_BE, mount, tilt) @ np.array([0.0, 0.0, -m * G])
    np.testing.assert_allclose(reading["force_S"], weight_S + [1.2, -0.8, 2.5], atol=1e-12)
    cog = np.array([0.002, -0.001, 0.0435])
    np.testing.assert_allclose(reading["torque_S"], np.cross(cog, weight_S) + [0.03, -0.02, 0.01], atol=1e-12)
    assert not reading["contact"].any()
    assert np.all(reading["status"] == 0)


def test_held_pose_has_no_inertial_wrench_even_with_inertia_on():
    world = SimWorld(motion=Hold(tilt_deg=30.0, roll_deg=20.0), inertia=True)
    reading = world.wrench(np.linspace(0, 5, 50), noise=False)
    assert np.all(reading["inertial_force_S"] == 0) and np.all(reading["inertial_torque_S"] == 0)
    # tool pointing down, tilted 30 deg: the weight makes 30 deg (plus the base tilt) with the tool axis
    weight_S = reading["gravity_force_S"][0]
    angle = np.degrees(np.arccos(weight_S[2] / np.linalg.norm(weight_S)))
    assert abs(angle - 30.0) < 2.0


def test_truth_matches_the_paper_model_when_mount_is_identity():
    """S_f = R_EB·B_f + f0 and S_tau = skew(p)·R_EB·B_f + tau0 with the truth's parameters."""
    world = SimWorld(motion=RandomTour(seed=11), seed=11, inertia=False)
    truth = world.truth()
    assert np.isclose(np.linalg.norm(truth["gravity_force_B"]), 0.35 * G)
    assert truth["mass_kg"] == 0.35
    np.testing.assert_allclose(truth["mount_rotation_SE"], 0.0)
    t = np.linspace(0, 30, 500)
    reading = world.wrench(t, noise=False)
    f_model = reading["R_EB"] @ truth["gravity_force_B"] + truth["bias_force_S"]
    tau_model = np.cross(truth["cog_S"], f_model - truth["bias_force_S"]) + truth["bias_torque_S"]
    np.testing.assert_allclose(reading["force_S"], f_model, atol=1e-12)
    np.testing.assert_allclose(reading["torque_S"], tau_model, atol=1e-12)


def test_gravity_force_B_is_the_tilted_weight():
    world = SimWorld(tool=ToolParams(mass=0.5), robot=RobotParams(base_tilt_BG=(0.1, 0.0, 0.0)))
    expected = 0.5 * G * np.array([0.0, np.sin(0.1), -np.cos(0.1)])  # rotating -z about x by +0.1 rad
    np.testing.assert_allclose(world.truth()["gravity_force_B"], expected, atol=1e-12)


def test_mount_rotation_rotates_the_gravity_reading():
    mount = np.array([0.1, -0.2, 0.3])
    common = {"motion": RandomTour(seed=2), "seed": 2, "inertia": False}
    plain = SimWorld(**common)
    mounted = SimWorld(sensor=SensorParams(mount_rotation_SE=mount), **common)
    t = np.linspace(0, 10, 200)
    a, b = plain.wrench(t, noise=False), mounted.wrench(t, noise=False)
    R_SE = Rotation.from_rotvec(mount).as_matrix()
    bias_f, bias_t = np.array([1.2, -0.8, 2.5]), np.array([0.03, -0.02, 0.01])
    np.testing.assert_allclose(b["force_S"] - bias_f, (a["force_S"] - bias_f) @ R_SE.T, atol=1e-12)
    assert np.abs(b["force_S"] - a["force_S"]).max() > 0.1  # the mount does change the reading
    np.testing.assert_allclose(mounted.truth()["mount_rotation_SE"], mount, atol=1e-12)
    # the centre of mass is fixed in S, so the torque is still cog × weight
    np.testing.assert_allclose(b["torque_S"] - bias_t, np.cross(world_cog(), b["force_S"] - bias_f), atol=1e-12)


def world_cog() -> np.ndarray:
    return np.array([0.002, -0.001, 0.0435])


# --------------------------------------------------------------------------- noise and determinism


def test_noise_std_per_axis_matches_config():
    noise_force, noise_torque = np.array([0.05, 0.1, 0.2]), np.array([0.002, 0.004, 0.008])
    world = SimWorld(sensor=SensorParams(noise_force_S=noise_force, noise_torque_S=noise_torque), motion=Hold(), seed=4)
    t = np.arange(40_000) * 1e-3
    residual = np.hstack(
        [
            world.wrench(t)["force_S"] - world.wrench(t, noise=False)["force_S"],
            world.wrench(t)["torque_S"] - world.wrench(t, noise=False)["torque_S"],
        ]
    )
    std = np.concatenate([noise_force, noise_torque])
    z = residual / std
    np.testing.assert_allclose(z.std(axis=0), 1.0, rtol=0.03)
    assert np.all(np.abs(z.mean(axis=0)) < 4 / np.sqrt(len(t)))
    corr = np.corrcoef(z.T)
    assert np.abs(corr - np.eye(6)).max() < 0.03  # axes independent
    lag1 = np.array([np.corrcoef(z[1:, i], z[:-1, i])[0, 1] for i in range(6)])
    assert np.abs(lag1).max() < 0.03  # white in time
    kurtosis = (z**4).mean(axis=0)
    np.testing.assert_allclose(kurtosis, 3.0, atol=0.2)  # Gaussian tails


def test_noise_defaults_are_ati_gamma_class():
    sensor = SensorParams()
    np.testing.assert_allclose(sensor.noise_force_S, 0.12)
    np.testing.assert_allclose(sensor.noise_torque_S, 0.01)


def test_chunked_requests_equal_one_shot_bit_for_bit():
    world = SimWorld(
        sensor=SensorParams(drift_force_rw_S=0.01, drift_torque_rw_S=0.001),
        seed=9,
        motion=RandomTour(seed=9, max_translation=0.02),
    )
    t = np.arange(5000) * 1e-3
    whole = world.wrench(t)
    fresh = SimWorld(
        sensor=SensorParams(drift_force_rw_S=0.01, drift_torque_rw_S=0.001),
        seed=9,
        motion=RandomTour(seed=9, max_translation=0.02),
    )
    chunks = list(itertools.pairwise([0, 1, 2, 17, 400, 401, 2999, 5000]))
    # ask for the chunks in reverse order: nothing may depend on what was asked before
    parts = {k: fresh.wrench(t[a:b]) for k, (a, b) in reversed(list(enumerate(chunks)))}
    for key in ("force_S", "torque_S", "status", "R_EB"):
        joined = np.concatenate([parts[k][key] for k in range(len(chunks))])
        assert np.array_equal(joined, whole[key]), key


def test_same_seed_same_data_other_seed_different():
    t = np.linspace(0, 6, 3000)
    a, b, c = (SimWorld.from_config({"seed": s}).wrench(t) for s in (5, 5, 6))
    assert np.array_equal(a["force_S"], b["force_S"]) and np.array_equal(a["torque_S"], b["torque_S"])
    assert not np.allclose(a["force_S"], c["force_S"], atol=0.01)
    assert not np.allclose(a["R_EB"], c["R_EB"], atol=0.01)  # the motion is seeded too
    # the noise alone also changes with the seed
    d, e = (SimWorld(motion=Hold(), seed=s).wrench(t) for s in (5, 6))
    assert not np.allclose(d["force_S"], e["force_S"], atol=0.01)


def test_repeated_calls_are_identical():
    world = SimWorld()
    t = np.linspace(0, 3, 100)
    assert np.array_equal(world.wrench(t)["force_S"], world.wrench(t)["force_S"])


def test_linear_drift_changes_bias_linearly():
    drift_f, drift_t = np.array([0.01, -0.02, 0.005]), np.array([1e-4, 0.0, -2e-4])
    world = SimWorld(sensor=SensorParams(drift_force_S=drift_f, drift_torque_S=drift_t), motion=Hold())
    np.testing.assert_allclose(world.truth(100.0)["bias_force_S"], np.array([1.2, -0.8, 2.5]) + 100 * drift_f)
    t = np.array([0.0, 50.0, 100.0])
    reading = world.wrench(t, noise=False)
    np.testing.assert_allclose(reading["force_S"] - reading["force_S"][0], t[:, None] * drift_f, atol=1e-12)
    np.testing.assert_allclose(reading["torque_S"] - reading["torque_S"][0], t[:, None] * drift_t, atol=1e-12)
    np.testing.assert_allclose(world.truth(t)["bias_torque_S"], [0.03, -0.02, 0.01] + t[:, None] * drift_t)


def test_random_walk_drift_has_the_configured_rate():
    rw_f, rw_t = np.array([0.01, 0.02, 0.04]), np.array([1e-3, 2e-3, 3e-3])
    world = SimWorld(sensor=SensorParams(drift_force_rw_S=rw_f, drift_torque_rw_S=rw_t), motion=Hold(), seed=8)
    dt = 0.01
    t = np.arange(20_001) * dt
    force, torque = world.bias(t)
    np.testing.assert_allclose(force[0], [1.2, -0.8, 2.5])
    increments = np.diff(np.hstack([force, torque]), axis=0) / np.sqrt(dt)
    np.testing.assert_allclose(increments.std(axis=0), np.concatenate([rw_f, rw_t]), rtol=0.03)
    # between grid points the path is continuous (no white noise hiding in the drift)
    fine = world.bias(np.arange(0, 1, 1e-4))[0]
    assert np.abs(np.diff(fine, axis=0)).max() < 5 * 0.04 * np.sqrt(dt)


# --------------------------------------------------------------------------- inertia


def test_constant_axial_rotation_gives_gyroscopic_torque():
    speed_deg_s = 72.0
    inertia = np.array([[2e-3, 0.0, 3e-4], [0.0, 2.5e-3, -2e-4], [3e-4, -2e-4, 1e-4]])
    tool = ToolParams(cog_S=(0.0, 0.0, 0.0435), inertia_S=inertia)
    world = SimWorld(tool=tool, motion=AxialRotation(speed_deg_s=speed_deg_s, turns=1, start_s=0.5))
    t = np.linspace(1.0, 4.0, 200)  # constant-speed part: ramp ends at 0.7 s, stop ramp starts at 5.2 s
    reading = world.wrench(t, noise=False)
    w = reading["angular_velocity_S"]
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), np.radians(speed_deg_s), rtol=1e-12)
    np.testing.assert_allclose(reading["angular_acceleration_S"], 0.0, atol=1e-12)
    expected = -np.cross(w, w @ inertia.T)  # the tool needs ω × Iω; the sensor feels the opposite
    assert np.abs(expected).max() > 1e-4
    np.testing.assert_allclose(reading["inertial_torque_S"], expected, atol=1e-15)
    np.testing.assert_allclose(reading["inertial_force_S"], 0.0, atol=1e-15)  # CoM on the axis


def test_off_axis_centre_of_mass_feels_centrifugal_force():
    cog = np.array([0.01, 0.0, 0.04])
    world = SimWorld(tool=ToolParams(cog_S=cog), motion=AxialRotation(speed_deg_s=45.0, turns=2))
    t = np.linspace(1.0, 6.0, 50)
    reading = world.wrench(t, noise=False)
    w = np.radians(45.0)
    # the CoM circles the z axis at radius 0.01 m: the sensor feels m ω² r outwards (+x in S)
    np.testing.assert_allclose(reading["inertial_force_S"], np.tile([0.35 * w**2 * 0.01, 0, 0], (50, 1)), atol=1e-15)


def _away_from_waypoints(t: np.ndarray, segment_s: float = 0.8, margin: float = 0.005) -> np.ndarray:
    """Drop times near a waypoint: the jerk jumps there, which spoils a second difference."""
    phase = np.mod(t, segment_s)
    return t[(phase > margin) & (phase < segment_s - margin)]


def _motion_world(inertia_S=None) -> SimWorld:
    tool = ToolParams(inertia_S=inertia_S) if inertia_S is not None else ToolParams()
    return SimWorld(
        tool=tool,
        sensor=SensorParams(mount_rotation_SE=(0.1, 0.2, -0.3), p_EoSo_E=(0.01, -0.02, 0.03)),
        motion=RandomTour(seed=21, segment_s=0.8, max_translation=0.05),
        seed=21,
    )


def test_inertial_force_matches_finite_difference_of_centre_of_mass():
    """Newton: f_inertial = −m a_cm, a_cm from a second central difference of the CoM position in B."""
    world = _motion_world()
    R_SE = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    p_EoScm_E = np.array([0.01, -0.02, 0.03]) + R_SE.T @ world_cog()

    def p_cm_B(t):
        R_BE, p_BoEo_B = world.pose(t)
        return p_BoEo_B + R_BE @ p_EoScm_E

    t = _away_from_waypoints(np.linspace(0.05, 8.0, 300))
    h = 2e-4
    a_cm_B = (p_cm_B(t + h) - 2 * p_cm_B(t) + p_cm_B(t - h)) / h**2
    reading = world.wrench(t, noise=False)
    R_SB = R_SE @ reading["R_EB"]
    expected = -0.35 * (R_SB @ a_cm_B[:, :, None])[:, :, 0]
    assert np.abs(expected).max() > 0.05
    np.testing.assert_allclose(reading["inertial_force_S"], expected, atol=1e-6)


def test_inertial_torque_matches_finite_difference_of_angular_momentum():
    """Euler: the sensor feels c × f_inertial − dH/dt, H the angular momentum about the CoM."""
    inertia = np.array([[2e-3, 1e-4, 3e-4], [1e-4, 2.5e-3, -2e-4], [3e-4, -2e-4, 1e-4]])
    world = _motion_world(inertia)
    R_SE = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()

    def H_B(t):
        d = 1e-6
        R = world.pose(t)[0]
        R_dot = (world.pose(t + d)[0] - world.pose(t - d)[0]) / (2 * d)
        w_B = vee(R_dot @ np.transpose(R, (0, 2, 1)))  # angular velocity from the pose alone
        R_BS = R @ R_SE.T
        I_B = R_BS @ inertia @ np.transpose(R_BS, (0, 2, 1))
        return (I_B @ w_B[:, :, None])[:, :, 0]

    t = _away_from_waypoints(np.linspace(0.05, 8.0, 300))
    h = 2e-4
    H_dot_B = (H_B(t + h) - H_B(t - h)) / (2 * h)
    reading = world.wrench(t, noise=False)
    R_SB = R_SE @ reading["R_EB"]
    H_dot_S = (R_SB @ H_dot_B[:, :, None])[:, :, 0]
    expected = np.cross(world_cog(), reading["inertial_force_S"]) - H_dot_S
    assert np.abs(H_dot_S).max() > 1e-3
    np.testing.assert_allclose(reading["inertial_torque_S"], expected, atol=1e-7)


def test_inertia_switch_removes_the_inertial_wrench():
    on = SimWorld(motion=RandomTour(seed=1), inertia=True).wrench(np.linspace(0, 5, 100), noise=False)
    off = SimWorld(motion=RandomTour(seed=1), inertia=False).wrench(np.linspace(0, 5, 100), noise=False)
    assert np.abs(on["inertial_force_S"]).max() > 1e-3
    np.testing.assert_allclose(on["force_S"] - on["inertial_force_S"], off["force_S"], atol=1e-12)
    np.testing.assert_allclose(on["torque_S"] - on["inertial_torque_S"], off["torque_S"], atol=1e-12)


# --------------------------------------------------------------------------- contacts


def test_indentation_profile_peak_and_zero_outside():
    event = Indentation(start=1.0, duration=2.0, peak_force=4.0, ramp=0.3)
    world = SimWorld(motion=Hold(tilt_deg=10.0), contacts=[event], inertia=False)
    t = np.arange(0.0, 4.0, 1e-3)
    reading = world.wrench(t, noise=False)
    magnitude = np.linalg.norm(reading["contact_force_S"], axis=1)
    outside = (t <= 1.0) | (t >= 3.0)
    assert np.all(magnitude[outside] == 0) and not reading["contact"][outside].any()
    assert reading["contact"][(t > 1.001) & (t < 2.999)].all()
    assert np.isclose(magnitude.max(), 4.0, rtol=1e-12)
    np.testing.assert_allclose(magnitude[(t >= 1.3) & (t <= 2.7)], 4.0, rtol=1e-12)
    rising = magnitude[(t > 1.0) & (t < 1.3)]
    assert np.all(np.diff(rising) > 0) and np.abs(np.diff(magnitude)).max() < 4.0 * np.pi / 2 * 1e-3 / 0.3 * 1.01
    # direction: the tissue pushes the tool up (+z of B)
    force_B = (np.transpose(reading["R_EB"], (0, 2, 1)) @ reading["contact_force_S"][:, :, None])[:, :, 0]
    np.testing.assert_allclose(force_B[2000], [0.0, 0.0, 4.0], atol=1e-12)
    # it acts at the tip and shows in the reading on top of the no-contact wrench
    np.testing.assert_allclose(reading["contact_torque_S"], np.cross([0.0, 0.0, 0.25], reading["contact_force_S"]))
    plain = SimWorld(motion=Hold(tilt_deg=10.0), inertia=False).wrench(t, noise=False)
    np.testing.assert_allclose(reading["force_S"] - plain["force_S"], reading["contact_force_S"], atol=1e-12)
    np.testing.assert_allclose(reading["torque_S"] - plain["torque_S"], reading["contact_torque_S"], atol=1e-12)


def test_hanging_104g_mass_weighs_1_02_newton_along_gravity():
    world = SimWorld(motion=AxialRotation(speed_deg_s=30.0, turns=1), contacts=[HangingMass(mass=0.104)])
    t = np.linspace(0.0, 12.0, 400)
    reading = world.wrench(t, noise=False)
    magnitude = np.linalg.norm(reading["contact_force_S"], axis=1)
    np.testing.assert_allclose(magnitude, 0.104 * G, rtol=1e-12)
    assert abs(magnitude[0] - 1.02) < 0.005
    weight_direction = reading["gravity_force_S"] / np.linalg.norm(reading["gravity_force_S"], axis=1)[:, None]
    np.testing.assert_allclose(reading["contact_force_S"], 0.104 * G * weight_direction, atol=1e-12)
    # the instrument is horizontal, so the load is lateral: no component along the tool axis (z of S)
    assert np.abs(reading["contact_force_S"][:, 2]).max() < 0.104 * G * 0.03
    np.testing.assert_allclose(
        reading["contact_torque_S"], np.cross([0, 0, 0.25], reading["contact_force_S"]), atol=1e-12
    )
    detached = SimWorld(motion=Hold(), contacts=[HangingMass(mass=0.104, start=1.0, duration=1.0)])
    flags = detached.wrench(np.array([0.5, 1.5, 2.5]), noise=False)["contact"]
    assert flags.tolist() == [False, True, False]


def test_saturation_clips_and_flags():
    world = SimWorld(motion=Hold(), contacts=[Indentation(start=1.0, duration=1.0, peak_force=300.0, ramp=0.2)])
    t = np.array([0.5, 1.5, 2.5])
    reading = world.wrench(t)
    assert reading["status"].tolist() == [0, STATUS_SATURATED, 0]
    # tool pointing down: the upward push is along −z of S
    assert reading["force_S"][1, 2] == -200.0
    assert np.all(np.abs(reading["force_S"]) <= [65, 65, 200]) and np.all(np.abs(reading["torque_S"]) <= 5)
    low = SimWorld(sensor=SensorParams(saturation_torque_S=0.05), motion=Hold(tilt_deg=60))
    assert np.all(low.wrench(t)["status"] & STATUS_SATURATED)  # |τx| ≈ 0.0435·3.43·sin 60° − 0.03 ≈ 0.1 N·m


# --------------------------------------------------------------------------- configuration

FULL_TOML = """
[world]
seed = 7
inertia = false
[world.tool]
mass = 0.5
cog = [0.0, 0.001, 0.05]
inertia_diag = [1e-3, 1e-3, 5e-5]
tip = [0.0, 0.0, 0.3]
[world.sensor]
bias_force = [1.0, 2.0, 3.0]
bias_torque = [0.1, 0.2, 0.3]
drift_force = [0.001, 0.0, 0.0]
drift_torque = [0.0, 0.0, 1e-5]
drift_force_rw = 0.002
drift_torque_rw = [1e-4, 1e-4, 2e-4]
noise_force = [0.1, 0.1, 0.2]
noise_torque = 0.005
saturation_force = 100
mount_rotation = [0.0, 0.0, 0.1]
offset = [0.0, 0.0, 0.01]
[world.robot]
base_tilt = [0.0, 0.01, 0.0]
position = [0.5, 0.1, 0.3]
[world.motion]
script = "axial_rotation"
speed_deg_s = 12
turns = 1
[[world.contacts]]
kind = "hanging_mass"
mass = 0.104
start = 2.0
[[world.contacts]]
kind = "indentation"
start = 1.0
peak_force = 3
direction_B = [0, 0, 2]
"""


def test_from_config_reads_every_table():
    world = SimWorld.from_config(tomllib.loads(FULL_TOML)["world"])
    assert world.seed == 7 and world.inertia is False
    assert world.tool.mass == 0.5
    np.testing.assert_allclose(np.diag(world.tool.inertia_S), [1e-3, 1e-3, 5e-5])
    np.testing.assert_allclose(world.tool.tip_S, [0, 0, 0.3])
    np.testing.assert_allclose(world.sensor.drift_force_rw_S, 0.002)
    np.testing.assert_allclose(world.sensor.noise_torque_S, 0.005)
    np.testing.assert_allclose(world.sensor.saturation_force_S, 100.0)
    np.testing.assert_allclose(world.sensor.saturation_torque_S, 5.0)  # default kept
    np.testing.assert_allclose(world.sensor.p_EoSo_E, [0, 0, 0.01])
    np.testing.assert_allclose(world.truth()["mount_rotation_SE"], [0, 0, 0.1], atol=1e-12)
    assert isinstance(world.motion, AxialRotation)
    np.testing.assert_allclose(world.pose(0.0)[1], [[0.5, 0.1, 0.3]])
    assert isinstance(world.contacts[0], HangingMass) and isinstance(world.contacts[1], Indentation)
    np.testing.assert_allclose(world.contacts[1].direction_B, [0, 0, 1])
    assert world.truth()["gravity_force_B"][0] < 0  # tilted about +y: −z tips towards −x


def test_empty_config_gives_the_defaults():
    world = SimWorld.from_config({})
    truth = world.truth()
    np.testing.assert_allclose(truth["bias_force_S"], [1.2, -0.8, 2.5])
    np.testing.assert_allclose(truth["cog_S"], [0.002, -0.001, 0.0435])
    assert isinstance(world.motion, RandomTour)
    assert np.abs(truth["gravity_force_B"][:2]).max() > 0  # default base tilt is not zero


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (
            {"sensor": {"noise_forse": 0.1}},
            "world.sensor.noise_forse: unknown option; did you mean noise_force?; known options: bias_force, ",
        ),
        ({"tool": {"mass": "heavy"}}, "world.tool.mass: must be a finite number > 0 (kg), got 'heavy'"),
        ({"tool": {"mass": -1.0}}, "world.tool.mass: must be a finite number > 0 (kg), got -1.0"),
        ({"tool": {"cog": [0, 0]}}, "world.tool.cog: must be 3 numbers, got [0, 0]"),
        (
            {"sensor": {"noise_torque": [0.1, "x", 0.1]}},
            "world.sensor.noise_torque: must be a number or 3 numbers, each >= 0, got [0.1, 'x', 0.1]",
        ),
        (
            {"sensor": {"noise_force": -0.1}},
            "world.sensor.noise_force: must be a number or 3 numbers, each >= 0, got -0.1",
        ),
        ({"inertia": "yes"}, "world.inertia: must be true or false, got 'yes'"),
        ({"seed": 1.5}, "world.seed: must be a whole number >= 0, got 1.5"),
        ({"gravity": 9.8}, "world.gravity: unknown option"),
        ({"robot": {"base_tilt": True}}, "world.robot.base_tilt: must be 3 numbers, got True"),
        ({"robot": 3}, "world.robot: must be a table, got 3"),
        (
            {"motion": {"script": "wiggle"}},
            "world.motion.script: must be 'random_tour', 'static_poses', 'axial_rotation', 'hold', 'indentation' "
            "or 'servo', got 'wiggle'",
        ),
        ({"motion": {"script": "axial_rotation", "speed": 3}}, "world.motion.speed: unknown option"),
        (
            {"motion": {"script": "axial_rotation", "turns": 1, "duration": 3}},
            "world.motion.turns: give either duration or turns, not both",
        ),
        ({"motion": {"segment_s": 0}}, "world.motion.segment_s: must be a finite number > 0 and <= 86400 (s), got 0"),
        (
            {"contacts": [{"kind": "poke"}]},
            "world.contacts[0].kind: must be 'indentation', 'hanging_mass', 'tissue' or 'cable', got 'poke'",
        ),
        (
            {"contacts": [{"kind": "hanging_mass"}, {"kind": "hanging_mass", "mas": 1}]},
            "world.contacts[1].mas: unknown option",
        ),
        ({"contacts": [{"kind": "indentation"}]}, "world.contacts[0].start: missing"),
        (
            {"contacts": [{"kind": "indentation", "start": 0, "duration": 0.1, "ramp": 0.2}]},
            "world.contacts[0].duration: must be >= 2·ramp = 0.4 s (a rise and a fall), got 0.1",
        ),
        (
            {"tool": {"inertia": [[1, 0, 0], [0, 1, 0], [0, 0]]}},
            "world.tool.inertia: must be a symmetric positive semi-definite 3x3 matrix (kg·m², 3 rows of 3 numbers), "
            "got [[1, 0, 0], [0, 1, 0], [0, 0]]",
        ),
    ],
)
def test_config_errors_name_the_key(table, message):
    with pytest.raises(ConfigError) as excinfo:
        SimWorld.from_config(table)
    text = str(excinfo.value)
    assert text.startswith(message), text
    assert "\n" not in text


def test_unknown_key_lists_the_known_ones():
    with pytest.raises(ConfigError, match=r"known options: .*noise_force"):
        SimWorld.from_config({"sensor": {"noise_forse": 0.1}})


def test_noise_may_be_a_scalar_or_three_numbers():
    a = SimWorld.from_config({"sensor": {"noise_force": 0.2}})
    b = SimWorld.from_config({"sensor": {"noise_force": [0.2, 0.2, 0.2]}})
    np.testing.assert_array_equal(a.sensor.noise_force_S, b.sensor.noise_force_S)


# --------------------------------------------------------------------------- small reads (the live loop)


def full_world(motion=None) -> SimWorld:
    """Every term switched on and nothing aligned with an axis: mount rotation, sensor
    offset, full inertia tensor, off-axis contact point, linear and random-walk drift."""
    return SimWorld(
        tool=ToolParams(
            cog_S=(0.003, -0.002, 0.05), inertia_S=((2e-3, 1e-4, 3e-4), (1e-4, 2.5e-3, -2e-4), (3e-4, -2e-4, 1e-4))
        ),
        sensor=SensorParams(
            mount_rotation_SE=(0.05, -0.08, 0.3),
            p_EoSo_E=(0.01, -0.02, 0.05),
            drift_force_S=(0.01, 0.0, -0.02),
            drift_force_rw_S=0.01,
            drift_torque_rw_S=0.001,
        ),
        robot=RobotParams(base_tilt_BG=(0.03, -0.02, 0.01)),
        motion=motion if motion is not None else RandomTour(seed=8, segment_s=0.4, max_translation=0.03),
        contacts=[
            HangingMass(start=0.1, duration=0.2, point_S=(0.01, 0.002, 0.1)),
            Indentation(start=0.25, duration=0.15, peak_force=80.0, ramp=0.05),
        ],
        seed=8,
    )


@pytest.mark.parametrize(
    "motion",
    [None, AxialRotation(speed_deg_s=200.0, turns=1, ramp_s=0.1, start_s=0.05), Hold(tilt_deg=20.0, roll_deg=30.0)],
    ids=["random_tour", "axial_rotation", "hold"],
)
def test_reads_of_one_to_seven_samples_equal_one_big_call_bit_for_bit(motion):
    """The live loop asks for 1 (1 kHz sensor) to 7 (7 kHz) samples at a time: every
    value must be exactly what one vectorised call over the whole stream gives."""
    t = np.arange(3500) / 7000.0
    whole = full_world(motion).wrench(t)
    assert whole["contact"].any() and (whole["status"] != 0).any()  # contacts and saturation are exercised
    small = full_world(motion)
    sizes = itertools.cycle([1, 7, 2, 7, 3, 1, 5, 7, 6, 4])
    cuts = [0]
    while cuts[-1] < len(t):
        cuts.append(min(len(t), cuts[-1] + next(sizes)))
    parts = [small.wrench(t[a:b]) for a, b in itertools.pairwise(cuts)]
    parts.append(small.wrench(t[123]))  # a scalar time
    for key, value in whole.items():
        joined = np.concatenate([part[key] for part in parts[:-1]])
        assert np.array_equal(joined, value), key
        assert np.array_equal(parts[-1][key], value[123:124]), key


def test_wrench_terms_match_the_textbook_cross_products():
    """Inertial, gravity and contact terms against the formulas of the module docstring,
    written out with np.cross (the code folds them into constant matrices)."""
    world = full_world()
    t = np.linspace(0.0, 3.0, 4001)
    reading = world.wrench(t, noise=False)
    state = world.motion_state(t)
    R_SE = Rotation.from_rotvec([0.05, -0.08, 0.3]).as_matrix()
    R_SB = R_SE @ np.transpose(state.R_BE, (0, 2, 1))
    m, c, I = world.tool.mass, world.tool.cog_S, world.tool.inertia_S  # noqa: E741 (the inertia's textbook symbol)
    p = np.array([0.01, -0.02, 0.05])

    def to_S(R, v):
        return (R @ v[..., None])[..., 0]

    w_E, alpha_E = state.w_BE_E, state.alpha_BE_E
    w_S, alpha_S = w_E @ R_SE.T, alpha_E @ R_SE.T
    a_So_B = state.a_BEo_B + to_S(state.R_BE, np.cross(alpha_E, p) + np.cross(w_E, np.cross(w_E, p)))
    a_cm_S = to_S(R_SB, a_So_B) + np.cross(alpha_S, c) + np.cross(w_S, np.cross(w_S, c))
    euler_S = alpha_S @ I.T + np.cross(w_S, w_S @ I.T)
    gravity_S = m * to_S(R_SB, world.gravity_accel_B)
    assert np.abs(m * a_cm_S).max() > 0.1 and np.abs(euler_S).max() > 1e-3  # the motion is lively

    np.testing.assert_allclose(reading["angular_velocity_S"], w_S, rtol=0, atol=1e-13)
    np.testing.assert_allclose(reading["angular_acceleration_S"], alpha_S, rtol=0, atol=1e-12)
    np.testing.assert_allclose(reading["inertial_force_S"], -m * a_cm_S, rtol=0, atol=1e-13)
    np.testing.assert_allclose(reading["inertial_torque_S"], np.cross(c, -m * a_cm_S) - euler_S, rtol=0, atol=1e-14)
    np.testing.assert_allclose(reading["gravity_force_S"], gravity_S, rtol=0, atol=1e-14)
    np.testing.assert_allclose(reading["gravity_torque_S"], np.cross(c, gravity_S), rtol=0, atol=1e-15)
    hanging = (t >= 0.1) & (t < 0.3) & ~((t >= 0.25) & (t <= 0.4))  # only the hanging mass acts
    assert hanging.sum() > 100
    np.testing.assert_allclose(
        reading["contact_torque_S"][hanging],
        np.cross([0.01, 0.002, 0.1], reading["contact_force_S"][hanging]),
        rtol=0,
        atol=1e-15,
    )


def reference_gaussian_noise(key: int, t_ns: np.ndarray, channels: int) -> np.ndarray:
    """The noise stream as first written: one pair of channels at a time."""

    def splitmix64(x):
        x = x + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return x ^ (x >> np.uint64(31))

    step = 0xD1B54A32D192ED03
    base = splitmix64(np.asarray(t_ns, dtype=np.int64).view(np.uint64) ^ np.uint64(key))
    out = np.empty((len(base), channels))
    for pair in range(channels // 2):
        u1 = (
            (splitmix64(base + np.uint64(((2 * pair + 1) * step) % 2**64)) >> np.uint64(11)).astype(float) + 0.5
        ) * 2.0**-53
        u2 = (
            (splitmix64(base + np.uint64(((2 * pair + 2) * step) % 2**64)) >> np.uint64(11)).astype(float) + 0.5
        ) * 2.0**-53
        out[:, 2 * pair] = np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
        out[:, 2 * pair + 1] = np.sqrt(-2.0 * np.log(u1)) * np.sin(2.0 * np.pi * u2)
    return out


def test_noise_stream_is_unchanged():
    """Seeded data must not change between versions: the same numbers as the first
    implementation (bit for bit), and as recorded from it (to libm's last bit)."""
    rng = np.random.default_rng(0)
    t_ns = np.concatenate([[0, 1, -1, 2**63 - 1, -(2**63)], rng.integers(-(2**62), 2**62, 5000)]).astype(np.int64)
    for key in (0, 8431846347943309920, 2**64 - 1):
        for channels in (2, 6):
            assert np.array_equal(gaussian_noise(key, t_ns, channels), reference_gaussian_noise(key, t_ns, channels))
    assert SimWorld(seed=1).channels.noise_key == 8431846347943309920
    recorded = np.array(
        [
            [
                -0.7883944535349952,
                0.6760612365399674,
                -0.15322416585264603,
                0.5034027412075973,
                0.9471304477575836,
                -0.8110150686916442,
            ],
            [
                0.20091427659102956,
                0.3609706879230142,
                -0.8741569433539794,
                -0.9764457130725596,
                -0.41830705953725683,
                -0.10732086071673083,
            ],
        ]
    )
    np.testing.assert_allclose(
        gaussian_noise(8431846347943309920, np.array([0, 2**62]), 6), recorded, rtol=1e-12, atol=0
    )


@pytest.mark.parametrize("rate_hz", [7000.0, 1000.0, 500.0, 125.0, 333.3, 6999.7])
def test_a_clock_read_tick_by_tick_hands_out_each_sample_once_at_its_formula_time(rate_hz):
    """``take`` (Python ints, what a live read uses) gives ``times`` (numpy) for every index, each once."""
    clock = SampleClock(rate_hz)
    t0_ns = 1_234_567_890_123
    clock.start(t0_ns)
    rng = np.random.default_rng(7)
    seqs, times = [], []
    now_ns = t0_ns
    for _ in range(3000):
        now_ns += int(rng.integers(0, 3_000_000))  # 0–3 ms ticks, some landing exactly on a sample
        if rng.random() < 0.1 and seqs:
            now_ns = times[-1]
        seq, t_ns = clock.take(now_ns)
        assert all(t <= now_ns for t in t_ns)
        seqs += list(seq)
        times += t_ns
    assert seqs == list(range(len(seqs)))
    assert times == clock.times(np.arange(len(seqs))).tolist()
    assert clock.times(np.array([len(seqs)]))[0] > now_ns  # nothing due was left behind
