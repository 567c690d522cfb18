"""The effects of issue 17, item 1, on new simulated recordings: a sensor warming up, a payload change.

Each recording is the lively 30 s, 250 Hz tour of ``test_discrepancy`` with one
of them hidden through the simulator's physics (an exponentially settling bias;
a ``HangingMass`` attached at one instant, away from the sensor origin), with
seeds used nowhere else. The workflow must name exactly that effect, find its
parameters and bring the force to the sensor's noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.plugins import ConfigError, Registry
from hapticlab.plugins.simworld import HangingMass, RandomTour, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.sessions.discrepancy.workflow import discrepancy

NOISE = 0.12  # N, the simulated sensor's default force noise per axis


def recording(tmp_path, seed: int, sensor=None, contacts=()):
    world = SimWorld(sensor=SensorParams(**(sensor or {})), contacts=list(contacts), seed=seed, inertia=False,
                     motion=RandomTour(seed=seed, segment_s=1.0, max_translation=0.05))
    path = tmp_path / f"hidden_{seed}.csv"
    write_csv(world, path, 30.0, 250.0)
    return path


@pytest.mark.parametrize(("seed", "tau_s"), [(61, 8.0), (62, 20.0)])
def test_a_sensor_warming_up_is_named_with_its_time_constant(tmp_path, seed, tau_s):
    settle_force_S, settle_torque_S = np.array([0.5, -0.4, 0.3]), np.array([0.02, -0.015, 0.01])
    path = recording(tmp_path, seed, {"warmup_force_S": settle_force_S, "warmup_torque_S": settle_torque_S,
                                      "warmup_tau_s": tau_s})
    result = discrepancy(path)
    assert result["effects"] == ["warm_up"], result["rounds"]
    found = result["final"]["params"]["warm_up"]
    assert found["tau_s"] == pytest.approx(tau_s, rel=0.15)
    np.testing.assert_allclose(found["settle_force_S"], settle_force_S, atol=0.06)
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE), result["final"]
    assert result["leftover"]["axes"] == []
    # the online estimator takes the options as they are: its bias-rate state follows the settling
    options = result["estimator_options"]
    kalman = Registry().create("estimator", "kalman", options, where="estimator")
    assert kalman.bias_rate


@pytest.mark.parametrize(("seed", "mass", "start"), [(63, 0.03, 12.0), (64, 0.1, 17.0)])
def test_a_payload_change_is_named_with_its_mass_point_and_instant(tmp_path, seed, mass, start):
    point_S = np.array([0.01, -0.005, 0.12])
    path = recording(tmp_path, seed, contacts=[HangingMass(mass=mass, start=start, point_S=point_S)])
    result = discrepancy(path)
    assert result["effects"] == ["payload_change"], result["rounds"]
    found = result["final"]["params"]["payload_change"]
    assert found["added_mass_kg"] == pytest.approx(mass, abs=0.004)
    assert found["t_change_s"] == pytest.approx(start, abs=0.02)  # 5 samples at 250 Hz
    assert found["point_S"][2] == pytest.approx(point_S[2], abs=0.03)
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE), result["final"]
    assert result["leftover"]["axes"] == []
    Registry().create("estimator", "kalman", result["estimator_options"], where="estimator")


def test_the_kalman_estimator_refuses_a_payload_change_it_would_not_watch_for():
    with pytest.raises(ConfigError, match="payload_change_s > 0"):
        Registry().create("estimator", "kalman", {"effects": ["payload_change"], "payload_change_s": 0.0},
                          where="estimator")


def test_the_simulated_warm_up_settles_to_the_bias():
    sensor = SensorParams(warmup_force_S=(0.5, 0.0, 0.0), warmup_torque_S=(0.0, 0.0, 0.02), warmup_tau_s=10.0)
    force, torque = SimWorld(sensor=sensor).bias(np.array([0.0, 10.0, 200.0]))
    np.testing.assert_allclose(force[:, 0] - sensor.bias_force_S[0], [0.5, 0.5 / np.e, 0.0], atol=1e-8)
    np.testing.assert_allclose(torque[:, 2] - sensor.bias_torque_S[2], [0.02, 0.02 / np.e, 0.0], atol=1e-8)
    with pytest.raises(ValueError, match="warmup_tau_s"):
        SensorParams(warmup_tau_s=0.0)
