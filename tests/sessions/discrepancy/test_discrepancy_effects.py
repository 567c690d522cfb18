"""Three effects of the library on new simulated recordings: a sensor warming up, a payload change, a loading
hysteresis.

Each recording is the lively 30 s, 250 Hz tour of ``test_discrepancy`` with one
of them hidden through the simulator's physics (an exponentially settling bias;
a ``HangingMass`` attached at one instant, away from the sensor origin; the
channels read through play operators), with seeds used nowhere else. The
workflow must name exactly that effect, find its parameters and bring the force
to the sensor's noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.sensor_model.play_kernel import play, play_signed
from hapticlab.plugins.simworld import HangingMass, RandomTour, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.sessions.discrepancy.workflow import discrepancy

NOISE = 0.12  # N, the simulated sensor's default force noise per axis


def recording(tmp_path, seed: int, sensor=None, contacts=()):
    world = SimWorld(
        sensor=SensorParams(**(sensor or {})),
        contacts=list(contacts),
        seed=seed,
        inertia=False,
        motion=RandomTour(seed=seed, segment_s=1.0, max_translation=0.05),
    )
    path = tmp_path / f"hidden_{seed}.csv"
    write_csv(world, path, 30.0, 250.0)
    return path


@pytest.mark.parametrize(("seed", "tau_s"), [(61, 8.0), (62, 20.0)])
def test_a_sensor_warming_up_is_named_with_its_time_constant(tmp_path, seed, tau_s):
    settle_force_S, settle_torque_S = np.array([0.5, -0.4, 0.3]), np.array([0.02, -0.015, 0.01])
    path = recording(
        tmp_path, seed, {"warmup_force_S": settle_force_S, "warmup_torque_S": settle_torque_S, "warmup_tau_s": tau_s}
    )
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


@pytest.mark.parametrize(("seed", "rate", "start", "duration"), [(341, 0.002, 0.0, 30.0), (342, 0.003, 5.0, 20.0)])
def test_a_payload_growing_gradually_is_named_a_ramp_not_a_step(tmp_path, seed, rate, start, duration):
    """A mass growing at the tip (a reservoir filling: 2 g/s over the whole 30 s, 3 g/s from 5 to 25 s) was named
    ``payload_change``, a step half-way (+29 g from 14.4 s; +40 g from 16.3 s), the force left at 1.04-1.16x the
    noise and four or five channels flagged. Now ``payload_ramp`` (it beats the step on held-out data: 71 % and
    77 % against 47 % and 56 %, with a smaller error in at least 8 of 10 folds), the force at the noise, nothing
    flagged."""
    from hapticlab.plugins.simworld.payload import GrowingMass

    path = recording(tmp_path, seed, contacts=[GrowingMass(rate=rate, start=start, duration=duration)])
    result = discrepancy(path)
    assert result["effects"] == ["payload_ramp"], result["rounds"]
    found = result["final"]["params"]["payload_ramp"]
    if start == 0.0:  # a ramp over the whole recording: its rate and where it hangs
        assert found["mass_rate_kg_s"] == pytest.approx(rate, rel=0.05)
        assert found["point_S"][2] == pytest.approx(0.25, abs=0.02)  # the tool tip
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.03 * NOISE), result["final"]
    assert result["leftover"]["axes"] == [] and result["estimator_options"] == {"effects": []}
    assert any(note.startswith("payload_ramp is not compensated online") for note in result["notes"])


def test_the_kalman_estimator_refuses_a_payload_change_it_would_not_watch_for():
    with pytest.raises(ConfigError, match="payload_change_s > 0"):
        Registry().create(
            "estimator", "kalman", {"effects": ["payload_change"], "payload_change_s": 0.0}, where="estimator"
        )


def test_the_simulated_warm_up_settles_to_the_bias():
    sensor = SensorParams(warmup_force_S=(0.5, 0.0, 0.0), warmup_torque_S=(0.0, 0.0, 0.02), warmup_tau_s=10.0)
    force, torque = SimWorld(sensor=sensor).bias(np.array([0.0, 10.0, 200.0]))
    np.testing.assert_allclose(force[:, 0] - sensor.bias_force_S[0], [0.5, 0.5 / np.e, 0.0], atol=1e-8)
    np.testing.assert_allclose(torque[:, 2] - sensor.bias_torque_S[2], [0.02, 0.02 / np.e, 0.0], atol=1e-8)
    with pytest.raises(ValueError, match="warmup_tau_s"):
        SensorParams(warmup_tau_s=0.0)


@pytest.mark.parametrize(("seed", "width"), [(65, 0.06), (66, 0.15), (67, 0.3)])
def test_a_loading_hysteresis_is_named_with_its_widths_not_as_a_time_lag(tmp_path, seed, width):
    """Fitted as a time lag, a hysteresis gave −30 to −178 ms; at 0.3 N the lag's linear test still
    wins the first round, and is dropped once the hysteresis is named beside it."""
    widths_force_S = np.array([width, 0.7 * width, 1.2 * width])
    path = recording(tmp_path, seed, {"hysteresis_force_S": widths_force_S})
    result = discrepancy(path)
    assert result["effects"] == ["hysteresis"], result["steps"]
    found = result["final"]["params"]["hysteresis"]
    np.testing.assert_allclose(found["width_force_S"], widths_force_S, atol=0.02)
    np.testing.assert_allclose(found["width_torque_S"], 0.0, atol=0.002)  # the torque channels have none
    assert np.all(np.array(result["final"]["rms_force_S"]) <= 1.10 * NOISE), result["final"]
    assert result["leftover"]["axes"] == []
    # the online estimator has no hysteresis: the options leave it out, and the report says so
    assert "hysteresis" not in result["estimator_options"]["effects"]
    assert any(note.startswith("hysteresis is not compensated online") for note in result["notes"])
    Registry().create("estimator", "kalman", result["estimator_options"], where="estimator")


def test_the_play_operator_kernel_matches_its_reference_and_stays_within_its_width():
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.normal(0.0, 0.05, (2000, 3)), axis=0)
    r = np.array([0.0, 0.1, 0.4])
    compiled, reference = np.empty_like(x), np.empty_like(x)
    last = play(x, r, x[0].copy(), compiled)
    play.py_func(x, r, x[0].copy(), reference)
    np.testing.assert_array_equal(compiled, reference)
    np.testing.assert_array_equal(last, compiled[-1])
    np.testing.assert_array_equal(compiled[:, 0], x[:, 0])  # width 0: the load itself
    lag = compiled - x
    assert np.all(np.abs(lag) <= r + 1e-12)
    assert np.all(np.abs(lag).max(axis=0)[1:] >= 0.99 * r[1:])  # the loop is reached both ways
    rising = np.diff(x[:, 2]) > 0
    held = np.abs(np.diff(compiled[:, 2])) == 0.0
    assert held[1:].sum() > 0 and not np.all(held[rising])
    # the signed widths: a negative one is the mirror image; the derivative at 0 is −sign(ẋ) where it moves
    np.testing.assert_allclose(play_signed(x, -r) - x, -(compiled - x), atol=1e-12)
    h = 1e-6
    slope = (play_signed(x, np.full(3, h)) - play_signed(x, np.full(3, -h))) / (2 * h)
    moving = np.abs(np.diff(x, axis=0)) > 4 * h
    np.testing.assert_allclose(slope[1:][moving], -np.sign(np.diff(x, axis=0))[moving], atol=1e-6)


def test_the_simulated_hysteresis_follows_the_loading_path_whatever_the_reads():
    """The same reading at a time however it is asked for (in chunks, out of order), and the reading minus
    the load is the play operator's: within ±r, typically −r while loading and +r while unloading (it crosses
    over once the load has turned back by 2r)."""
    sensor = SensorParams(hysteresis_force_S=(0.2, 0.0, 0.1), hysteresis_torque_S=(0.0, 0.01, 0.0))
    motion = RandomTour(seed=9, segment_s=1.0, max_translation=0.05)
    t = np.arange(0.0, 6.0, 1 / 700)
    whole = SimWorld(sensor=sensor, seed=9, motion=motion).wrench(t, noise=False)
    world = SimWorld(sensor=sensor, seed=9, motion=motion)
    late_first = world.wrench(t[3000:], noise=False)["force_S"]
    chunks = np.concatenate([world.wrench(t[i : min(i + 7, 3000)], noise=False)["force_S"] for i in range(0, 3000, 7)])
    np.testing.assert_array_equal(np.concatenate([chunks, late_first]), whole["force_S"])
    load = SimWorld(seed=9, motion=motion).wrench(t, noise=False)
    lag_S = np.concatenate([whole["force_S"] - load["force_S"], whole["torque_S"] - load["torque_S"]], axis=1)
    widths = np.array([0.2, 0.0, 0.1, 0.0, 0.01, 0.0])
    assert np.all(np.abs(lag_S) <= widths + 1e-9)
    np.testing.assert_allclose(np.abs(lag_S).max(axis=0), widths, rtol=1e-3)
    # the play operator along these samples (the world follows it on its 1 ms grid: the same up to reversals
    # between two samples)
    x = np.concatenate([load["force_S"], load["torque_S"]], axis=1)
    np.testing.assert_allclose(lag_S, play_signed(x, widths) - x, atol=1e-4)
    rate = np.gradient(x[:, 0], t)
    assert np.median(lag_S[rate > 0.5, 0]) == pytest.approx(-0.2) and np.median(lag_S[rate < -0.5, 0]) == pytest.approx(
        0.2
    )
    with pytest.raises(ValueError, match="hysteresis_force_S"):
        SensorParams(hysteresis_force_S=(-0.1, 0.0, 0.0))
