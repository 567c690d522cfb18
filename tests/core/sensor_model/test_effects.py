"""The sensor model along a recorded motion (core/sensor_model/) and the built-in effect models.

Expected values come from the simulated world (its own physics, analytic
motion derivatives), from scipy, or from first principles, never from the
code under test.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.core.host.registry import Registry, make_plugin_manager
from hapticlab.core.sensor_model import STAGES, Effect, Model, motion_from_poses
from hapticlab.core.sensor_model.model import BASE_STEPS
from hapticlab.core.sensor_model.motion import savgol, savgol_t
from hapticlab.plugins.effects.bias_drift import BiasDrift
from hapticlab.plugins.effects.gain_crosstalk import GainCrosstalk, gain_matrix
from hapticlab.plugins.effects.hysteresis import Hysteresis
from hapticlab.plugins.effects.inertia import Inertia
from hapticlab.plugins.effects.mount_rotation import MountRotation
from hapticlab.plugins.effects.time_lag import TimeLag
from hapticlab.plugins.simworld import RandomTour, RobotParams, SensorParams, SimWorld

GF = np.array([[0.02, 0.01, -0.005], [0.01, -0.015, 0.008], [-0.005, 0.008, -0.005]])  # traceless
GT = np.array([[-0.01, 0.004, 0.0], [0.004, 0.02, -0.01], [0.0, -0.01, -0.01]])
BUILTINS = {
    "mount_rotation": MountRotation,
    "bias_drift": BiasDrift,
    "inertia": Inertia,
    "time_lag": TimeLag,
    "gain_crosstalk": GainCrosstalk,
    "hysteresis": Hysteresis,
}


def recorded(world: SimWorld, duration: float = 12.0, rate: float = 500.0, positions: bool = True):
    """Sample times, the motion as the kinematics report it, and the noise-free reading."""
    t = np.arange(0.0, duration, 1.0 / rate)
    R_BE, p = world.pose(t)
    motion = motion_from_poses(t, quat_wxyz_from_matrix(R_BE), p if positions else None)
    return t, motion, world.wrench(t, noise=False)


def lively(seed: int = 5) -> RandomTour:
    return RandomTour(seed=seed, segment_s=0.8, max_translation=0.05)


def test_builtins_are_registered_as_effects():
    registry = Registry(make_plugin_manager(load_entry_points=False))
    assert set(BUILTINS) <= set(registry.names("effect"))
    for name, cls in BUILTINS.items():
        assert registry.get("effect", name).factory is cls
        assert registry.get("effect", name).origin == f"hapticlab.plugins.effects.{name}"


def test_savgol_is_scipys():
    x = np.cumsum(np.random.default_rng(1).normal(size=(400, 4)), axis=0)
    for deriv in (0, 1, 2):
        np.testing.assert_allclose(
            savgol(x, 11, deriv, 0.004),
            savgol_filter(x, 11, 3, deriv=deriv, delta=0.004, axis=0, mode="interp"),
            rtol=1e-9,
            atol=1e-9 * np.abs(x).max() / 0.004**deriv,
        )


def test_motion_derivatives_match_the_analytic_ones():
    world = SimWorld(motion=lively(), seed=5)
    t, motion, _ = recorded(world)
    truth = world.motion_state(t)
    inner = slice(50, -50)  # the filter's edge windows extrapolate
    for got, want, name in (
        (motion.w_E, truth.w_BE_E, "w"),
        (motion.alpha_E, truth.alpha_BE_E, "alpha"),
        (motion.a_B, truth.a_BEo_B, "a"),
    ):
        err = np.sqrt(np.mean((got[inner] - want[inner]) ** 2))
        assert err < 0.02 * np.sqrt(np.mean(want[inner] ** 2)), name


def test_derivatives_use_the_actual_time_steps_of_jittered_stamps():
    """Stamps ±30 % of a period off the grid: a filter on a uniform grid misreads the spacing as motion."""
    world = SimWorld(motion=lively(), seed=5)
    rng = np.random.default_rng(3)
    t = np.sort(np.arange(6000) / 500 + rng.uniform(-0.3, 0.3, 6000) / 500)
    R_BE, p = world.pose(t)
    motion = motion_from_poses(t, quat_wxyz_from_matrix(R_BE), p)
    truth = world.motion_state(t)
    inner = slice(50, -50)
    for got, want, name in (
        (motion.w_E, truth.w_BE_E, "w"),
        (motion.alpha_E, truth.alpha_BE_E, "alpha"),
        (motion.a_B, truth.a_BEo_B, "a"),
    ):
        err = np.sqrt(np.mean((got[inner] - want[inner]) ** 2))
        assert err < 0.02 * np.sqrt(np.mean(want[inner] ** 2)), name


def test_savgol_on_real_times_is_savgol_on_a_uniform_grid():
    x = np.cumsum(np.random.default_rng(1).normal(size=(400, 4)), axis=0)
    t = np.arange(400) * 0.004
    for deriv in (0, 1, 2):
        np.testing.assert_allclose(
            savgol_t(x, t, 11, deriv),
            savgol(x, 11, deriv, 0.004),
            rtol=1e-9,
            atol=1e-9 * np.abs(x).max() / 0.004**deriv,
        )


def test_an_index_time_base_has_no_derivatives():
    world = SimWorld(seed=2)
    t = np.arange(200.0)
    motion = motion_from_poses(t, quat_wxyz_from_matrix(world.pose(t * 0.05)[0]), time_base="index")
    assert motion.w_E is None and not motion.has_time and motion.t_ref == pytest.approx(99.5)


def test_shifted_motion_is_the_recorded_pose_at_t_plus_dt_and_shifts_add_up():
    world = SimWorld(motion=lively(), seed=5)
    t, motion, _ = recorded(world)
    inner = slice(100, -100)
    for dt in (0.004, -0.0073):
        shifted = motion.shifted(dt)
        want = world.pose(t + dt)[0].transpose(0, 2, 1)
        assert np.abs(shifted.R_EB[inner] - want[inner]).max() < 1e-5  # slerp between 2 ms samples
        np.testing.assert_array_equal(shifted.t, t)
    np.testing.assert_allclose(motion.shifted(0.003).shifted(0.002).R_EB, motion.shifted(0.005).R_EB, atol=1e-12)
    assert motion.shifted(0.003).shifted(-0.003) is motion
    with pytest.raises(ValueError, match="shifted"):
        motion.shifted(0.01).subset(slice(0, 10))


def test_the_model_with_the_true_effects_reproduces_the_simulated_sensor():
    """Every effect at once, with the world's own parameters: the prediction is the noise-free reading."""
    mount, lag, drift = np.deg2rad([2.0, -1.5, 1.0]), 0.008, np.array([0.5, -0.3, 0.4, 0.01, -0.02, 0.015]) / 60
    offset_E = np.array([0.01, -0.02, 0.05])  # the sensor origin 5 cm out from the flange
    world = SimWorld(
        sensor=SensorParams(
            mount_rotation_SE=mount,
            gain_force_S=GF,
            gain_torque_S=GT,
            drift_force_S=drift[:3],
            drift_torque_S=drift[3:],
            p_EoSo_E=offset_E,
        ),
        robot=RobotParams(kinematics_lag_s=lag),
        motion=lively(),
        seed=5,
        inertia=True,
    )
    _t, motion, reading = recorded(world)
    truth = world.truth()
    model = Model(
        [(n, BUILTINS[n]()) for n in ("time_lag", "mount_rotation", "inertia", "gain_crosstalk", "bias_drift")]
    )
    I = truth["inertia_S"]  # noqa: E741 (the inertia tensor's usual name)
    theta = np.concatenate(
        [
            truth["gravity_force_B"],
            truth["bias_force_S"] + drift[:3] * motion.t_ref,
            truth["cog_S"],
            truth["bias_torque_S"] + drift[3:] * motion.t_ref,
            [lag],
            mount,
            [1.0, I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]],
            Rotation.from_rotvec(mount).as_matrix() @ offset_E,
            [GF[0, 0], GF[1, 1], GF[0, 1], GF[0, 2], GF[1, 2], GT[0, 0], GT[1, 1], GT[0, 1], GT[0, 2], GT[1, 2]],
            drift,
        ]
    )
    error = np.concatenate([reading["force_S"], reading["torque_S"]], axis=1) - model.predict6(motion, theta)
    inner = slice(100, -100)
    rms = np.sqrt(np.mean(error[inner] ** 2, axis=0))
    assert np.all(rms[:3] < 0.02 * 0.12), rms  # 2 % of the sensor noise: derivatives from the poses
    assert np.all(rms[3:] < 0.02 * 0.01), rms
    # and without the effects the gap is far beyond the noise
    base = Model().predict6(motion, theta[:12])
    assert np.sqrt(np.mean((reading["force_S"] - base[:, :3]) ** 2)) > 0.1


def test_the_hysteresis_effect_is_the_simulated_sensors_play_operator():
    """A hysteresis after a calibration error, with a mount rotation: the model with the world's widths gives its
    noise-free reading (the world follows the operator on a 1 ms grid, the model along the 500 Hz samples: the
    same but for load reversals between two samples). Without inertia the load is exact: the hysteresis keeps
    any error of the load at a reversal for as long as it holds, so the model's derivative errors (up to
    0.025 N at the tour's corners) would stay in it."""
    widths = np.array([0.05, 0.1, 0.08, 0.002, 0.001, 0.003])
    mount = np.deg2rad([2.0, -1.5, 1.0])
    world = SimWorld(
        sensor=SensorParams(
            mount_rotation_SE=mount,
            gain_force_S=GF,
            gain_torque_S=GT,
            hysteresis_force_S=widths[:3],
            hysteresis_torque_S=widths[3:],
        ),
        motion=lively(),
        seed=5,
        inertia=False,
    )
    _, motion, reading = recorded(world)
    truth = world.truth()
    model = Model([(n, BUILTINS[n]()) for n in ("mount_rotation", "gain_crosstalk", "hysteresis")])
    gains = [GF[0, 0], GF[1, 1], GF[0, 1], GF[0, 2], GF[1, 2], GT[0, 0], GT[1, 1], GT[0, 1], GT[0, 2], GT[1, 2]]
    theta = np.concatenate(
        [truth["gravity_force_B"], truth["bias_force_S"], truth["cog_S"], truth["bias_torque_S"], mount, gains, widths]
    )
    y = np.concatenate([reading["force_S"], reading["torque_S"]], axis=1)
    error = y - model.predict6(motion, theta)
    assert np.all(np.abs(error[:, :3]).max(axis=0) < 1e-4) and np.all(np.abs(error[:, 3:]).max(axis=0) < 1e-5)
    without = y - model.predict6(motion, np.concatenate([theta[:-6], np.zeros(6)]))
    np.testing.assert_allclose(np.abs(without).max(axis=0), widths, rtol=0.01)  # the loop it leaves out


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_each_effect_switched_off_changes_nothing_and_reports_json(name):
    world = SimWorld(motion=lively(), seed=3, inertia=False)
    _, motion, _ = recorded(world, duration=4.0)
    effect = BUILTINS[name]()
    assert effect.check(motion) is None
    assert effect.stage in STAGES and len(effect.labels) == len(effect.steps) == len(effect.initial())
    base = np.concatenate([world.truth()[k] for k in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S")])
    model = Model([(name, effect)])
    np.testing.assert_array_equal(model.predict6(motion, model.initial(base)), Model().predict6(motion, base))
    params = np.linspace(0.001, 0.002, len(effect.labels))
    json.dumps(effect.describe(params))
    assert isinstance(effect.summary(params), str)
    options = effect.estimator_options(params)
    assert set(options) <= {"time_lag_s", "gain_force_S", "gain_torque_S", "mount_rotation_SE"}


def test_effect_parameters_mean_what_they_say():
    world = SimWorld(motion=lively(), seed=3, inertia=False)
    _, motion, _ = recorded(world, duration=4.0)
    base = np.concatenate([world.truth()[k] for k in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S")])
    weight_S = Model().weight_S(motion, base)
    # mount rotation: the weight turns by R_SE
    rotvec = np.array([0.01, -0.02, 0.03])
    model = Model([("mount_rotation", MountRotation())])
    np.testing.assert_allclose(
        model.weight_S(motion, np.r_[base, rotvec]), weight_S @ Rotation.from_rotvec(rotvec).as_matrix().T, atol=1e-12
    )
    # gain: (I + G) times the true wrench, before the bias
    p = np.array([0.02, -0.015, 0.01, -0.005, 0.008, -0.01, 0.02, 0.004, 0.0, -0.01])
    np.testing.assert_allclose(gain_matrix(p[:5]), GF)
    force, _ = Model([("gain_crosstalk", GainCrosstalk())]).predict(motion, np.r_[base, p])
    np.testing.assert_allclose(force, weight_S @ (np.eye(3) + GF).T + base[3:6], atol=1e-12)
    # drift: rate times the time from the middle of the recording
    force, _torque = Model([("bias_drift", BiasDrift())]).predict(motion, np.r_[base, [1, 2, 3, 4, 5, 6]])
    np.testing.assert_allclose(
        force - (weight_S + base[3:6]), (motion.t - motion.t_ref)[:, None] * [1, 2, 3], atol=1e-9
    )
    # time lag: the pose at t + τ
    force, _ = Model([("time_lag", TimeLag())]).predict(motion, np.r_[base, 0.01])
    np.testing.assert_allclose(force, Model().predict(motion.shifted(0.01), base)[0], atol=1e-12)


def test_effects_skip_recordings_that_lack_their_prerequisites():
    world = SimWorld(seed=2)
    index = motion_from_poses(
        np.arange(100.0), quat_wxyz_from_matrix(world.pose(np.arange(100.0))[0]), time_base="index"
    )
    assert "time base" in TimeLag().check(index) and "time base" in Inertia().check(index)
    assert MountRotation().check(index) is None and BiasDrift().check(index) is None
    t = np.arange(0, 60, 0.1)
    slow = motion_from_poses(t, quat_wxyz_from_matrix(world.pose(t)[0]))
    assert "samples/s" in Inertia().check(slow) and TimeLag().check(slow) is None
    still = motion_from_poses(t, np.tile([1.0, 0, 0, 0], (len(t), 1)))
    assert "hardly turns" in TimeLag().check(still) and "never changes" in MountRotation().check(still)
    t = np.arange(0, 4, 0.002)
    no_positions = motion_from_poses(t, quat_wxyz_from_matrix(world.pose(t)[0]))
    assert "only the rotational terms" in Inertia().notes(no_positions)[0]


def test_a_model_refuses_a_badly_declared_effect():
    class Bad(Effect):
        stage = "somewhere"
        labels = ("a",)
        steps = (1e-3,)

    with pytest.raises(ValueError, match="effect bad: stage 'somewhere'"):
        Model([("bad", Bad())])
    Bad.stage, Bad.steps = "load", ()
    with pytest.raises(ValueError, match="1 labels but 0 steps"):
        Model([("bad", Bad())])


def test_jacobian_of_linear_parameters_is_exact():
    world = SimWorld(motion=lively(), seed=3, inertia=False)
    _, motion, _ = recorded(world, duration=2.0)
    base = np.concatenate([world.truth()[k] for k in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S")])
    J = Model([("bias_drift", BiasDrift())]).jacobian(motion, np.r_[base, np.zeros(6)])
    np.testing.assert_allclose(J[:, :3, 3:6], np.broadcast_to(np.eye(3), (len(motion), 3, 3)), atol=1e-6)
    np.testing.assert_allclose(J[:, 3:, 9:12], np.broadcast_to(np.eye(3), (len(motion), 3, 3)), atol=1e-6)
    np.testing.assert_allclose(J[:, 0, 12], motion.t - motion.t_ref, atol=1e-6)
    np.testing.assert_allclose(J[:, :3, 0:3], motion.R_EB, atol=1e-6)


def test_terms_kept_along_a_motion_change_no_bit_of_a_prediction():
    """A Jacobian reuses the terms its predictions share (``ModelState.cached``) and the predictions themselves:
    each column is the same to the last bit as predictions on a fresh copy of the motion, and what is kept is
    read-only."""
    world = SimWorld(sensor=SensorParams(mount_rotation_SE=np.deg2rad([2.0, -1.5, 1.0])), motion=lively(), seed=4)
    _, motion, _ = recorded(world, duration=2.0)
    model = Model([(n, BUILTINS[n]()) for n in ("time_lag", "mount_rotation", "inertia")])
    base = np.concatenate([world.truth()[k] for k in ("gravity_force_B", "bias_force_S", "cog_S", "bias_torque_S")])
    theta = np.r_[base, 0.004, np.deg2rad([1.0, -0.5, 0.5]), 1.0, 1e-3, 2e-3, 1e-3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.03]
    J = model.jacobian(motion, theta)
    lagged = model._timed(motion, theta)  # the terms are kept along the motion after the time lag
    kept = [a for v in lagged.cache.values() for a in (v if isinstance(v, tuple) else (v,))]
    assert kept and not any(a.flags.writeable for a in kept)

    def fresh(th: np.ndarray) -> np.ndarray:
        return Model(model.effects).predict6(dataclasses.replace(motion), th)  # (a new motion keeps nothing)

    steps = np.concatenate([BASE_STEPS] + [np.asarray(e.steps, float) for _, e in model.effects])
    for i in (0, 4, 7, 12, 14, 17, 25):  # weight, bias, cog, lag, mount, inertia's Ixx and offset
        plus, minus = theta.copy(), theta.copy()
        plus[i] += steps[i]
        minus[i] -= steps[i]
        low = fresh(theta) if i < 12 else fresh(minus)  # forward differences for the base, central for effects
        expected = (fresh(plus) - low) / (steps[i] if i < 12 else 2 * steps[i])
        assert np.array_equal(J[:, :, i], expected), model.labels[i]
    kept_prediction = model.predict6(motion, theta)  # kept from the Jacobian's own
    assert np.array_equal(kept_prediction, fresh(theta)) and not kept_prediction.flags.writeable
