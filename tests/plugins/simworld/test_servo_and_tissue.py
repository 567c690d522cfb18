"""The simulated robot under a position servo (teleoperation's robot) and the tissue the tool presses into."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hapticlab.core.host.registry import ConfigError
from hapticlab.plugins.kinematics.sim import ServoedSimKinematics, SimKinematics, sim_kinematics
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.simworld.config import parse_world_table
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.servo import ServoedMotion
from hapticlab.plugins.simworld.tissue import Tissue


def vee(M: np.ndarray) -> np.ndarray:
    return 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)


def test_a_step_target_is_reached_within_the_speed_and_acceleration_limits():
    motion = ServoedMotion(bandwidth_hz=8.0, max_speed=0.1, max_accel=2.0)
    R_0, p_0 = motion.target
    motion.servo_cp(0.2, R_0, p_0 + [0.05, 0.0, -0.03])
    t = np.arange(0.0, 2.0, 0.0005)
    state = motion.evaluate(t)
    assert np.allclose(state.p_BoEo_B[t < 0.2], p_0)  # nothing moves before the command
    assert np.allclose(state.p_BoEo_B[-1], p_0 + [0.05, 0.0, -0.03], atol=1e-5)
    assert np.linalg.norm(state.v_BEo_B, axis=1).max() <= 0.1 + 1e-9
    assert np.linalg.norm(state.a_BEo_B, axis=1).max() <= 2.0 + 1e-9
    # the velocity and acceleration reported are the position's derivatives (central differences inside
    # each 1 ms step: the acceleration is held over a step and jumps between steps)
    mid, h = np.arange(0.2, 1.0, 0.001) + 0.0005, 1e-5
    p_after, p_before = motion.evaluate(mid + h).p_BoEo_B, motion.evaluate(mid - h).p_BoEo_B
    at = motion.evaluate(mid)
    assert np.abs((p_after - p_before) / (2 * h) - at.v_BEo_B).max() < 1e-7
    assert np.abs((p_after - 2 * at.p_BoEo_B + p_before) / h**2 - at.a_BEo_B).max() < 1e-2
    assert np.allclose(state.R_BE, R_0)


def test_a_rotation_target_is_reached_and_the_angular_velocity_is_the_orientation_s_derivative():
    motion = ServoedMotion(max_angular_speed=1.0)
    R_0, p_0 = motion.target
    R_goal = Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix() @ R_0
    motion.servo_cp(0.1, R_goal, p_0)
    t = np.arange(0.1, 2.5, 0.001) + 0.0005
    state = motion.evaluate(t)
    assert np.abs(state.R_BE[-1] - R_goal).max() < 1e-6
    assert np.abs(state.R_BE @ state.R_BE.transpose(0, 2, 1) - np.eye(3)).max() < 1e-9  # still rotations
    assert np.linalg.norm(state.w_BE_E, axis=1).max() <= 1.0 + 1e-9
    h = 1e-5
    R_dot = (motion.evaluate(t + h).R_BE - motion.evaluate(t - h).R_BE) / (2 * h)
    w_fd = vee(state.R_BE.transpose(0, 2, 1) @ R_dot)
    assert np.abs(w_fd - state.w_BE_E).max() < 1e-4  # rad/s (first order in the step's angle, ~1e-3 rad)


def test_the_past_stays_as_it_was_when_the_target_changes():
    """Causal: a new target changes the motion from its time on, never what was already integrated."""
    motion = ServoedMotion()
    R_0, p_0 = motion.target
    motion.servo_cp(0.1, R_0, p_0 + [0.0, 0.02, 0.0])
    before = motion.evaluate(np.arange(0.0, 0.5, 0.001))
    motion.servo_cp(0.5, R_0, p_0 - [0.0, 0.02, 0.0])
    again = motion.evaluate(np.arange(0.0, 0.5, 0.001))
    assert np.array_equal(before.p_BoEo_B, again.p_BoEo_B) and np.array_equal(before.R_BE, again.R_BE)
    later = motion.evaluate(np.array([1.5]))
    assert later.p_BoEo_B[0, 1] < p_0[1]


def test_a_servoed_sensor_with_hysteresis_reads_what_the_targets_made_of_its_past():
    """The hysteresis follows the loading path; under a servo that path is only known up to now, so a read
    before a target was sent must not fix the path beyond it: the same reads as a world that had the target
    from the start."""
    targets = [(0.05, [0.0, 0.0, 0.03]), (0.15, [0.0, 0.02, -0.01])]

    def world():
        return SimWorld.from_config({"motion": {"script": "servo"}, "sensor": {"hysteresis_force": 0.05}})

    told, late = world(), world()
    R_0, p_0 = told.motion.target
    for t, step in targets:
        told.servo_cp(t, R_0, p_0 + step)
    t = np.arange(0.0, 0.4, 0.001)
    reads = []
    for now in t:
        for when, step in targets:
            if abs(when - now) < 1e-9:
                late.servo_cp(when, R_0, p_0 + step)
        reads.append(late.wrench(np.array([now]), noise=False)["force_S"][0])
    np.testing.assert_array_equal(np.array(reads), told.wrench(t, noise=False)["force_S"])


def test_asked_one_sample_at_a_time_or_all_at_once_the_motion_is_the_same():
    one, other = ServoedMotion(), ServoedMotion()
    R_0, p_0 = one.target
    for motion in (one, other):
        motion.servo_cp(0.05, R_0, p_0 + [0.01, 0.0, 0.0])
    t = np.arange(0.0, 0.3, 1 / 7000)
    singles = np.concatenate([one.evaluate(np.array([x])).p_BoEo_B for x in t])
    assert np.allclose(singles, other.evaluate(t).p_BoEo_B, rtol=0, atol=1e-15)


def test_the_compiled_state_is_the_numpy_reference_s():
    """``evaluate`` (plugins.simworld.servo_kernel) against ``evaluate_reference`` (numpy) on a move that turns and
    translates at once, at 7 kHz times inside and on the 1 ms steps' edges, and before the first step."""
    motion = ServoedMotion(max_angular_speed=2.0)
    R_0, p_0 = motion.target
    R_goal = Rotation.from_rotvec([0.4, -0.3, 0.5]).as_matrix() @ R_0
    motion.servo_cp(0.02, R_goal, p_0 + [0.03, -0.02, 0.01])
    t = np.concatenate([np.arange(-0.001, 0.6, 1 / 7000), np.arange(0.0, 0.6, 0.001)])
    compiled, reference = motion.evaluate(t), motion.evaluate_reference(t)
    assert np.abs(reference.w_BE_E).max() > 0.5 and np.abs(reference.v_BEo_B).max() > 0.02  # it moves
    for field in ("R_BE", "p_BoEo_B", "v_BEo_B", "a_BEo_B", "w_BE_E", "alpha_BE_E"):
        assert np.allclose(getattr(compiled, field), getattr(reference, field), rtol=0, atol=1e-14), field


def test_a_live_robot_reports_the_quaternions_the_numpy_path_gives():
    """``plugins.kinematics.sim_kernel`` (a live world's poses, one at a time) against the numpy path the prefetching
    kinematics take: random orientations (each of Shepperd's four rows chosen) with the encoders' jitter
    and without, and a servoed robot turning, read through ``_poses`` and ``_poses_reference``."""
    from hapticlab.core.frames import quat_multiply, quat_wxyz_from_matrix
    from hapticlab.plugins.kinematics.sim_kernel import reported_quat

    R = Rotation.random(400, random_state=5).as_matrix()
    delta = np.random.default_rng(6).normal(0.0, 1e-3, (400, 3))
    plain, turned = np.empty((400, 4)), np.empty((400, 4))
    reported_quat(R, delta, False, plain)
    reported_quat(R, delta, True, turned)
    expected = quat_wxyz_from_matrix(R)
    assert (
        len(
            {
                int(np.argmax(np.c_[np.trace(R, axis1=1, axis2=2), np.diagonal(R, axis1=1, axis2=2)][k]))
                for k in range(400)
            }
        )
        == 4
    )  # every branch
    assert np.allclose(plain, expected, rtol=0, atol=1e-15)
    expected = expected + 0.5 * quat_multiply(expected, np.column_stack([np.zeros(400), delta]))
    assert np.allclose(turned, expected / np.linalg.norm(expected, axis=1)[:, None], rtol=0, atol=1e-15)

    world = tissue_world()
    kinematics = sim_kinematics(rate_hz=500.0, encoder_noise=1e-4, world=world)
    R_0, p_0 = world.motion.target
    world.servo_cp(0.01, Rotation.from_rotvec([0.0, 0.6, 0.3]).as_matrix() @ R_0, p_0)
    t_ns = np.arange(0, 1_000_000_000, 2_000_000)
    live, reference = kinematics._poses(t_ns / 1e9, t_ns), kinematics._poses_reference(t_ns / 1e9, t_ns)
    assert np.allclose(live[0], reference[0], rtol=0, atol=1e-15) and np.array_equal(live[1], reference[1])
    assert np.ptp(live[0][:, 2]) > 0.1  # it turned


def test_a_non_finite_target_is_refused_and_the_robot_keeps_its_last():
    motion = ServoedMotion()
    R_0, p_0 = motion.target
    with pytest.raises(ValueError, match="finite"):
        motion.servo_cp(0.1, R_0, np.array([np.nan, 0.0, 0.0]))
    assert np.allclose(motion.evaluate(np.array([1.0])).p_BoEo_B[0], p_0)


def test_tissue_pushes_back_in_proportion_to_depth_and_never_pulls():
    tissue = Tissue(surface_B=(0.0, 0.0, 0.1), normal_B=(0.0, 0.0, 2.0), stiffness=300.0, damping=2.0)
    x = np.array([[0.0, 0.0, 0.12], [0.0, 0.0, 0.1], [0.0, 0.0, 0.09], [0.0, 0.0, 0.09]])
    v = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 5.0]])  # the last leaves fast
    force = tissue.force_B_at(x, v)
    assert np.allclose(force[:2], 0.0)  # above the surface, at it: nothing (a continuous start)
    assert np.allclose(force[2], [0.0, 0.0, 3.0])  # 1 cm deep at 300 N/m, along the outward normal
    assert np.allclose(force[3], 0.0)  # withdrawing faster than the tissue recovers: no pull
    with pytest.raises(ValueError, match=r"^stiffness: must be a finite number > 0 \(N/m\), got 0.0$"):
        Tissue(stiffness=0.0)


def tissue_world(**motion) -> SimWorld:
    """The tool pointing down with its tip 5 mm above tissue (tip 0.25 m below the flange at z 0.35 m)."""
    return SimWorld.from_config(
        {
            "seed": 3,
            "motion": {"script": "servo", **motion},
            "contacts": [{"kind": "tissue", "surface_B": [0.45, 0.0, 0.095]}],
        }
    )


def test_the_sensor_feels_the_tissue_the_robot_is_sent_into():
    world = tissue_world()
    R_0, p_0 = world.motion.target
    assert not world.wrench(np.array([0.5]))["contact"].any()
    world.servo_cp(0.5, R_0, p_0 - [0.0, 0.0, 0.015])  # 1 cm into the tissue
    reading = world.wrench(np.array([2.5]), noise=False)
    R_SB = world.R_SE @ R_0.T
    assert reading["contact"].all()
    assert np.allclose(reading["contact_force_S"][0], R_SB @ [0.0, 0.0, 3.0], atol=1e-3)
    tip_S = world.tool.tip_S
    assert np.allclose(reading["contact_torque_S"][0], np.cross(tip_S, reading["contact_force_S"][0]))


def test_the_simulated_devices_read_the_world_as_the_robot_moves_not_ahead_of_it():
    """A live world is only known up to now: the sim sensor must not hand out readings computed before a command."""
    world = tissue_world()
    sensor = SimSensor(rate_hz=1000.0, world=world)
    kinematics = sim_kinematics(rate_hz=500.0, encoder_noise=0.0, world=world)
    assert isinstance(kinematics, ServoedSimKinematics)
    assert not isinstance(sim_kinematics(world=SimWorld()), ServoedSimKinematics)
    sensor.open(0)
    kinematics.open(0)
    R_0, p_0 = world.motion.target
    sensor.read(100_000_000)
    kinematics.read(100_000_000)
    kinematics.servo_cp(100_000_000, R_0, p_0 - [0.0, 0.0, 0.015])
    later = sensor.read(2_000_000_000)
    poses = kinematics.read(2_000_000_000)
    assert np.isclose(poses[-1].p_BoEo_B[2], p_0[2] - 0.015, atol=1e-6)
    fresh = SimWorld.from_config(
        {"seed": 3, "motion": {"script": "servo"}, "contacts": [{"kind": "tissue", "surface_B": [0.45, 0.0, 0.095]}]}
    )
    fresh.servo_cp(0.1, R_0, p_0 - [0.0, 0.0, 0.015])
    expected = fresh.wrench(np.array([s.t_ns for s in later]) / 1e9)
    assert np.array_equal(np.array([s.force_S for s in later]), expected["force_S"])
    assert np.linalg.norm(later[-1].force_S - world.wrench(np.array([0.05]))["force_S"][0]) > 2.5


def test_world_tables_for_teleoperation_are_checked():
    spec = parse_world_table(
        {
            "motion": {"script": "servo", "bandwidth_hz": 5.0, "tilt_deg": 10.0},
            "contacts": [{"kind": "tissue", "stiffness": 500.0}],
        }
    )
    assert isinstance(spec.motion, ServoedMotion) and spec.contacts[0].stiffness == 500.0
    with pytest.raises(ConfigError, match=r"world.motion.gain: unknown option"):
        parse_world_table({"motion": {"script": "servo", "gain": 1.0}})
    with pytest.raises(
        ConfigError, match=r"^world.contacts\[0\].stiffness: must be a finite number > 0 \(N/m\), got -1.0$"
    ):
        parse_world_table({"contacts": [{"kind": "tissue", "stiffness": -1.0}]})
    with pytest.raises(ConfigError, match=r"^world.motion.step_s: must be <= 0.01 s and <= 1/20 of the servo's period"):
        parse_world_table({"motion": {"script": "servo", "step_s": 0.05}})
    with pytest.raises(TypeError, match="servo"):
        SimWorld().servo_cp(0.0, np.eye(3), np.zeros(3))
    assert isinstance(sim_kinematics(world=SimWorld()), SimKinematics)


def test_a_live_worlds_devices_compute_their_noise_ahead_and_read_the_bits_of_one_sample_at_a_time():
    """The sim sensor and kinematics of a servoed world compute the time-only part of their readings (the
    channels' bias and noise, the encoders' jitter, the robot wrench's noise) ahead in chunks, and share one
    motion state and contact force per tick; the physics stays one sample at a time. Driven as the live
    loop drives them (prepare ahead, read, then a new target every tick, turning and pressing into the
    tissue), they read the same bits as a twin world asked sample by sample with nothing computed ahead."""
    world, twin = tissue_world(), tissue_world()
    sensor = SimSensor(rate_hz=1000.0, world=world)
    kinematics = sim_kinematics(rate_hz=500.0, encoder_noise=1e-4, world=world)
    twin_kinematics = sim_kinematics(rate_hz=500.0, encoder_noise=1e-4, world=twin)
    sensor.open(0)
    kinematics.open(0)
    R_0, p_0 = world.motion.target
    wrenches, poses, expected_wrenches, expected_poses = [], [], [], []
    for tick in range(1001):
        now_ns, t = tick * 1_000_000, np.array([tick * 1e-3])
        sensor.prepare(now_ns + 10_000_000)
        kinematics.prepare(now_ns + 10_000_000)
        block = sensor.read_block(now_ns)
        wrenches.append(np.hstack([block.force_S, block.torque_S]))
        poses += [np.hstack([s.quat_BE, s.p_BoEo_B, s.wrench_B]) for s in kinematics.read(now_ns)]
        reading = twin.wrench(t)
        expected_wrenches.append(np.hstack([reading["force_S"], reading["torque_S"]]))
        if tick % 2 == 0:
            ns = np.array([now_ns])
            quat, p = twin_kinematics._poses(t, ns)
            expected_poses.append(np.hstack([quat, p, twin_kinematics._wrenches(t, ns)])[0])
        R_goal = Rotation.from_rotvec([0.3 * tick * 1e-3, 0.0, 0.0]).as_matrix() @ R_0
        for w in (world, twin):
            w.servo_cp(tick * 1e-3, R_goal, p_0 - [0.0, 0.0, 0.015 * min(tick * 2e-3, 1.0)])
    np.testing.assert_array_equal(np.vstack(wrenches), np.vstack(expected_wrenches))
    np.testing.assert_array_equal(np.array(poses), np.array(expected_poses))
    assert len(poses) == 501 and np.ptp(np.vstack(wrenches)[:, 2]) > 1.0  # it pressed into the tissue
