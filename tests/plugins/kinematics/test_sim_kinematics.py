"""The ``sim`` kinematics plugin: poses of the shared world at the kinematics rate."""

from __future__ import annotations

import importlib

import numpy as np
import pluggy
import pytest
from scipy.spatial.transform import Rotation

from hapticlab.core.frames import quat_wxyz_from_matrix as quat_wxyz_from_matrices
from hapticlab.core.host import hookspecs
from hapticlab.core.host.interfaces import KinematicsSource
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.plugins.kinematics.sim import SimKinematics
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.simworld import RandomTour, SimWorld

T0 = 987_654_321


def registry_with_sim_plugins() -> Registry:
    pm = pluggy.PluginManager("hapticlab")
    pm.add_hookspecs(hookspecs)
    for name in ("hapticlab.plugins.sensors.sim", "hapticlab.plugins.kinematics.sim"):
        pm.register(importlib.import_module(name), name=name)
    return Registry(pm)


def test_registered_as_sim_and_built_through_the_registry():
    registry = registry_with_sim_plugins()
    assert registry.names("kinematics") == ["sim"]
    kinematics = registry.create("kinematics", "sim", {"rate_hz": 125}, where="kinematics", world=SimWorld())
    assert isinstance(kinematics, SimKinematics) and isinstance(kinematics, KinematicsSource)
    assert kinematics.rate_hz == 125.0


def test_without_a_world_the_error_says_so():
    with pytest.raises(ConfigError, match="world"):
        SimKinematics()


def test_poses_follow_the_world_at_the_kinematics_rate():
    world = SimWorld(motion=RandomTour(seed=2, max_translation=0.03), seed=2)
    kinematics = SimKinematics(rate_hz=500.0, encoder_noise=0.0, world=world)
    kinematics.open(T0)
    poses = kinematics.read(T0 + 3_000_000_000) + kinematics.read(T0 + 4_000_000_000)
    assert len(poses) == 2001
    t_ns = np.array([p.t_ns for p in poses])
    np.testing.assert_array_equal(t_ns, T0 + np.arange(2001) * 2_000_000)
    quat = np.array([p.quat_BE for p in poses])
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    assert np.all(quat[:, 0] >= 0)
    R_BE, p_BoEo_B = world.pose((t_ns - T0) / 1e9)
    R_from_quat = Rotation.from_quat(quat, scalar_first=True).as_matrix()
    np.testing.assert_allclose(R_from_quat, R_BE, atol=1e-12)
    np.testing.assert_allclose(np.array([p.p_BoEo_B for p in poses]), p_BoEo_B, atol=0)
    assert poses[0].joints is None


def test_sensor_and_kinematics_share_one_world():
    """At a common time the sensor's gravity reading matches the kinematics' orientation."""
    world = SimWorld(seed=4, inertia=False)
    sensor, kinematics = (
        SimSensor(rate_hz=1000.0, world=world),
        SimKinematics(rate_hz=125.0, encoder_noise=0.0, world=world),
    )
    sensor.open(T0)
    kinematics.open(T0)
    wrench = {s.t_ns: s for s in sensor.read(T0 + 2_000_000_000)}
    truth = world.truth()
    for pose in kinematics.read(T0 + 2_000_000_000):
        R_EB = Rotation.from_quat(pose.quat_BE, scalar_first=True).as_matrix().T
        expected = R_EB @ truth["gravity_force_B"] + truth["bias_force_S"]
        assert np.abs(wrench[pose.t_ns].force_S - expected).max() < 6 * 0.12  # only the sensor noise differs


def test_quaternions_match_scipy_including_half_turns():
    special = Rotation.from_rotvec(
        [
            [0, 0, 0],
            [np.pi, 0, 0],
            [0, np.pi, 0],
            [0, 0, np.pi],
            [np.pi / np.sqrt(2), np.pi / np.sqrt(2), 0],
            [1e-9, 0, 0],
            [0, 0, 3.1415926],
        ]
    )
    R = np.concatenate([special.as_matrix(), Rotation.random(20_000, random_state=3).as_matrix()])
    quat = quat_wxyz_from_matrices(R)
    expected = Rotation.from_matrix(R).as_quat(scalar_first=True)
    expected *= np.where(expected[:, :1] < 0, -1.0, 1.0)
    np.testing.assert_allclose(quat, expected, rtol=0, atol=1e-15)
    assert np.all(quat[:, 0] >= 0)
    np.testing.assert_allclose(Rotation.from_quat(quat, scalar_first=True).as_matrix(), R, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(quat_wxyz_from_matrices(np.asfortranarray(R[:50])), quat[:50])  # any layout


def test_one_pose_per_read_gives_exactly_one_big_read():
    def kinematics():
        world = SimWorld(motion=RandomTour(seed=9, segment_s=0.3, max_translation=0.03), seed=9)
        source = SimKinematics(rate_hz=1000.0, encoder_noise=0.0, world=world)
        source.open(T0)
        return source

    whole = kinematics().read(T0 + 2_000_000_000)
    live = kinematics()
    reads = [live.read(T0 + ms * 1_000_000) for ms in range(2001)]
    assert {len(r) for r in reads} == {1}
    poses = [pose for r in reads for pose in r]
    for field in ("t_ns", "quat_BE", "p_BoEo_B"):
        assert np.array_equal([getattr(p, field) for p in poses], [getattr(p, field) for p in whole]), field
    with pytest.raises(ValueError, match="read-only"):
        poses[0].quat_BE[0] = 1.0  # read-only views
