"""The simulated sensor's calibration error (gain/crosstalk) and the kinematics clock offset."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.host.registry import ConfigError
from hapticlab.plugins.kinematics.sim import SimKinematics
from hapticlab.plugins.simworld import RandomTour, RobotParams, SensorParams, SimWorld

GAIN_F = np.array([[0.02, 0.01, -0.005], [0.01, -0.015, 0.008], [-0.005, 0.008, -0.005]])
GAIN_T = np.array([[-0.01, 0.004, 0.0], [0.004, 0.02, -0.01], [0.0, -0.01, -0.01]])


def lively(seed: int = 4) -> RandomTour:
    return RandomTour(seed=seed, segment_s=0.8, max_translation=0.05)


def test_gain_multiplies_the_true_wrench_before_the_bias():
    t = np.linspace(0.0, 6.0, 601)
    plain = SimWorld(motion=lively(), seed=4)
    gained = SimWorld(sensor=SensorParams(gain_force_S=GAIN_F, gain_torque_S=GAIN_T), motion=lively(), seed=4)
    a, b = plain.wrench(t, noise=False), gained.wrench(t, noise=False)
    true_force = a["force_S"] - a["bias_force_S"]  # gravity + inertia, inertia on by default
    true_torque = a["torque_S"] - a["bias_torque_S"]
    assert np.abs(a["inertial_force_S"]).max() > 0.05  # the product covers the inertial terms too
    np.testing.assert_allclose(b["force_S"], true_force @ (np.eye(3) + GAIN_F).T + a["bias_force_S"], atol=1e-12)
    np.testing.assert_allclose(b["torque_S"], true_torque @ (np.eye(3) + GAIN_T).T + a["bias_torque_S"], atol=1e-12)
    # the truth channels are the physics, not the reading
    np.testing.assert_array_equal(a["gravity_force_S"], b["gravity_force_S"])
    np.testing.assert_array_equal(gained.truth()["gain_force_S"], GAIN_F)


def test_zero_gain_and_lag_leave_every_reading_bit_identical():
    t = np.linspace(0.0, 3.0, 301)
    default = SimWorld(motion=lively(), seed=2)
    explicit = SimWorld(
        sensor=SensorParams(gain_force_S=np.zeros((3, 3)), gain_torque_S=np.zeros((3, 3))),
        robot=RobotParams(kinematics_lag_s=0.0),
        motion=lively(),
        seed=2,
    )
    for key, value in default.wrench(t).items():
        np.testing.assert_array_equal(value, explicit.wrench(t)[key], err_msg=key)
    np.testing.assert_array_equal(default.pose(t)[0], explicit.pose(t)[0])


@pytest.mark.parametrize("lag", [0.008, -0.005])
def test_kinematics_lag_shifts_the_reported_pose_not_the_wrench(lag):
    t = np.linspace(0.5, 5.0, 451)
    plain = SimWorld(motion=lively(), seed=3)
    lagged = SimWorld(robot=RobotParams(kinematics_lag_s=lag), motion=lively(), seed=3)
    # τ > 0: the pose stamped t is the one truly reached at t − τ
    np.testing.assert_allclose(lagged.pose(t)[0], plain.pose(t - lag)[0], atol=1e-14)
    np.testing.assert_allclose(lagged.pose(t)[1], plain.pose(t - lag)[1], atol=1e-14)
    np.testing.assert_array_equal(lagged.wrench(t)["force_S"], plain.wrench(t)["force_S"])
    # the sim kinematics plugin stamps them the same way
    kin = SimKinematics(rate_hz=100.0, encoder_noise=0.0, world=lagged)
    kin.open(0)
    poses = kin.read(2_000_000_000)
    stamps = np.array([p.t_ns for p in poses]) / 1e9
    R_true = plain.pose(stamps - lag)[0]
    R_reported = np.array([lagged.pose(s)[0][0] for s in stamps])
    np.testing.assert_allclose(R_reported, R_true, atol=1e-14)
    assert lagged.truth()["kinematics_lag_s"] == lag


def test_config_keys():
    world = SimWorld.from_config(
        {"sensor": {"gain_force": GAIN_F.tolist(), "gain_torque": GAIN_T.tolist()}, "robot": {"kinematics_lag": -0.004}}
    )
    np.testing.assert_array_equal(world.sensor.gain_force_S, GAIN_F)
    np.testing.assert_array_equal(world.sensor.gain_torque_S, GAIN_T)
    assert world.robot.kinematics_lag_s == -0.004


@pytest.mark.parametrize(
    ("table", "message"),
    [
        (
            {"sensor": {"gain_force": [[0, 0, 0], [0, 0, 0]]}},
            "world.sensor.gain_force: must be a 3x3 matrix (3 rows of 3 numbers), each > -0.5 and < 0.5 "
            "(a calibration error), got [[0, 0, 0], [0, 0, 0]]",
        ),
        (
            {"sensor": {"gain_torque": [[0, 0, 0], [0, "x", 0], [0, 0, 0]]}},
            "world.sensor.gain_torque: must be a 3x3 matrix (3 rows of 3 numbers), each > -0.5 and < 0.5",
        ),
        (
            {"sensor": {"gain_force": [[0.6, 0, 0], [0, 0, 0], [0, 0, 0]]}},
            "world.sensor.gain_force: must be a 3x3 matrix (3 rows of 3 numbers), each > -0.5 and < 0.5 "
            "(a calibration error), got [[0.6, 0, 0], [0, 0, 0], [0, 0, 0]]",
        ),
        (
            {"robot": {"kinematics_lag": "5ms"}},
            "world.robot.kinematics_lag: must be a finite number >= -1 and <= 1 (s), got '5ms'",
        ),
        (
            {"robot": {"kinematics_lag": 2.0}},
            "world.robot.kinematics_lag: must be a finite number >= -1 and <= 1 (s), got 2.0",
        ),
    ],
)
def test_config_errors_name_the_key(table, message):
    with pytest.raises(ConfigError) as excinfo:
        SimWorld.from_config(table)
    assert str(excinfo.value).startswith(message), str(excinfo.value)
    assert "\n" not in str(excinfo.value)
