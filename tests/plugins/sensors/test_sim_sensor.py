"""The ``sim`` sensor plugin: sample timing, chunked reads, saturation status, registration."""

from __future__ import annotations

import importlib
import math

import numpy as np
import pluggy
import pytest

from hapticlab.core.host import hookspecs
from hapticlab.core.host.interfaces import SensorSource
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.types import STATUS_OK, STATUS_SATURATED, WrenchSample
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.simworld import Hold, Indentation, RandomTour, SensorParams, SimWorld, ToolParams
from hapticlab.plugins.simworld.prefetch import PREFETCH_MAX_SAMPLES, PREFETCH_S

T0 = 1_234_567_890_123  # an arbitrary session clock at open, ns


def registry_with_sim_plugins() -> Registry:
    """A Registry holding only the simulated sensor and kinematics (other built-ins may not exist yet)."""
    pm = pluggy.PluginManager("hapticlab")
    pm.add_hookspecs(hookspecs)
    for name in ("hapticlab.plugins.sensors.sim", "hapticlab.plugins.kinematics.sim"):
        pm.register(importlib.import_module(name), name=name)
    return Registry(pm)


def as_arrays(samples: list[WrenchSample]):
    return (
        np.array([s.t_ns for s in samples]),
        np.array([s.force_S for s in samples]),
        np.array([s.torque_S for s in samples]),
        np.array([s.seq for s in samples]),
        np.array([s.status for s in samples]),
    )


def test_registered_as_sim_and_built_through_the_registry():
    registry = registry_with_sim_plugins()
    assert "sim" in registry.names("sensor")
    world = SimWorld()
    sensor = registry.create("sensor", "sim", {"rate_hz": 2000}, where="sensor", world=world)
    assert isinstance(sensor, SimSensor) and isinstance(sensor, SensorSource)
    assert sensor.rate_hz == 2000.0 and sensor.world is world
    with pytest.raises(ConfigError, match=r"^sensor\.rate: unknown option"):
        registry.create("sensor", "sim", {"rate": 2000}, where="sensor", world=world)


def test_without_a_world_the_error_says_so():
    with pytest.raises(ConfigError, match="world"):
        SimSensor(rate_hz=1000.0)
    with pytest.raises(ConfigError, match="world"):
        registry_with_sim_plugins().create("sensor", "sim", {})


def test_samples_are_on_the_rate_grid_and_returned_once():
    sensor = SimSensor(rate_hz=1000.0, world=SimWorld())
    with pytest.raises(RuntimeError, match="before open"):
        sensor.read(T0)
    sensor.open(T0)
    first = sensor.read(T0 + 10_000_500)
    assert [s.seq for s in first] == list(range(11))
    assert [s.t_ns for s in first] == [T0 + i * 1_000_000 for i in range(11)]
    assert sensor.read(T0 + 10_000_999) == []
    assert [s.seq for s in sensor.read(T0 + 12_000_000)] == [11, 12]  # a sample exactly at until_ns is included
    assert sensor.read(T0 - 5) == []
    sample = first[3]
    assert sample.force_S.shape == (3,) and sample.torque_S.shape == (3,) and sample.status == 0
    sensor.close()


def test_samples_match_the_world_at_world_time():
    world = SimWorld(seed=3)
    sensor = SimSensor(rate_hz=500.0, world=world)
    sensor.open(T0)
    t_ns, force, torque, seq, _ = as_arrays(sensor.read(T0 + 2_000_000_000))
    expected = world.wrench(seq / 500.0)
    assert np.array_equal(force, expected["force_S"]) and np.array_equal(torque, expected["torque_S"])
    np.testing.assert_array_equal((t_ns - T0) / 1e9, seq / 500.0)


@pytest.mark.parametrize("rate_hz", [1000.0, 7000.0])
def test_chunked_reads_equal_one_read(rate_hz):
    def world():
        return SimWorld(seed=17)

    whole = SimSensor(rate_hz=rate_hz, world=world())
    whole.open(T0)
    one = as_arrays(whole.read(T0 + 3_000_000_000))
    chunked = SimSensor(rate_hz=rate_hz, world=world())
    chunked.open(T0)
    pieces = []
    for until in np.cumsum([0, 123_457, 1, 999_999, 2_500_000, 777_777_777, 2_000_000_000]):
        pieces += chunked.read(T0 + int(min(until, 3_000_000_000)))
    pieces += chunked.read(T0 + 3_000_000_000)
    parts = as_arrays(pieces)
    for a, b in zip(one, parts):
        assert np.array_equal(a, b)
    assert len(one[0]) == int(3.0 * rate_hz) + 1
    assert np.all(np.diff(one[0]) > 0) and np.array_equal(one[3], np.arange(len(one[3])))


def test_saturated_samples_carry_the_status_bit():
    world = SimWorld(motion=Hold(), contacts=[Indentation(start=0.1, duration=0.2, peak_force=400.0, ramp=0.05)])
    sensor = SimSensor(rate_hz=1000.0, world=world)
    sensor.open(0)
    t_ns, force, _, _, status = as_arrays(sensor.read(400_000_000))
    saturated = (status & STATUS_SATURATED) != 0
    t = t_ns / 1e9
    assert saturated[(t > 0.16) & (t < 0.24)].all() and not saturated[(t < 0.1) | (t > 0.3)].any()
    assert np.abs(force).max() <= 200.0


def test_samples_are_read_only():
    sensor = SimSensor(world=SimWorld())
    sensor.open(0)
    sample = sensor.read(5_000_000)[0]
    with pytest.raises(ValueError, match="read-only"):
        sample.force_S[0] = 1.0


def full_world() -> SimWorld:
    """Every term on and nothing axis-aligned: mount, offset, full inertia, drift, a contact."""
    return SimWorld(
        tool=ToolParams(inertia_S=((2e-3, 1e-4, 3e-4), (1e-4, 2.5e-3, -2e-4), (3e-4, -2e-4, 1e-4))),
        sensor=SensorParams(
            mount_rotation_SE=(0.05, -0.08, 0.3), p_EoSo_E=(0.01, -0.02, 0.05), drift_torque_rw_S=0.001
        ),
        motion=RandomTour(seed=6, segment_s=0.5, max_translation=0.03),
        contacts=[Indentation(start=0.3, duration=0.4, peak_force=3.0, ramp=0.1)],
        seed=6,
    )


@pytest.mark.parametrize("rate_hz", [1000.0, 7000.0])
def test_a_live_loop_reads_exactly_what_one_big_read_gives(rate_hz):
    """A 1 kHz loop reads 1 sample (1 kHz sensor) or 7 (7 kHz) at a time: the same
    values, bit for bit, as one vectorised read of the whole stream."""
    whole = SimSensor(rate_hz=rate_hz, world=full_world())
    whole.open(T0)
    one = as_arrays(whole.read(T0 + 1_000_000_000))
    live = SimSensor(rate_hz=rate_hz, world=full_world())
    live.open(T0)
    reads = [live.read(T0 + ms * 1_000_000) for ms in range(1001)]
    assert max(len(r) for r in reads) == round(rate_hz / 1000)
    for a, b in zip(one, as_arrays([s for r in reads for s in r])):
        assert np.array_equal(a, b)
    sample = reads[500][0]
    assert type(sample.t_ns) is int and type(sample.seq) is int and type(sample.status) is int


@pytest.mark.parametrize("rate_hz", [1000.0, 7000.0])
def test_prepared_reads_are_the_same_and_compute_nothing(rate_hz):
    """prepare(until) (a paced loop's idle time) computes the world ahead; the reads after it hand out the
    same bits as reads without it and compute nothing themselves."""
    plain = SimSensor(rate_hz=rate_hz, world=full_world())
    plain.open(T0)
    prepared = SimSensor(rate_hz=rate_hz, world=full_world())
    prepared.open(T0)
    calls = []
    compute = prepared._ahead.compute
    prepared._ahead.compute = lambda seq: calls.append(("read" if reading else "prepare", len(seq))) or compute(seq)
    a, b = [], []
    for ms in range(1, 301):
        until = T0 + ms * 1_000_000
        reading = False
        prepared.prepare(until)
        reading = True
        b += prepared.read(until)
        a += plain.read(until)
        reading = False
        prepared.prepare(until + 1_000_000)  # the next tick's, as the loop asks
    for x, y in zip(as_arrays(a), as_arrays(b)):
        assert np.array_equal(x, y)
    assert calls and {kind for kind, _ in calls} == {"prepare"}  # all while idle
    # 301 ms asked for (the last prepare looks a tick ahead): chunks of up to 1 s, at most 400 samples each
    chunk = min(round(PREFETCH_S * rate_hz), PREFETCH_MAX_SAMPLES)
    assert chunk == {1000.0: 400, 7000.0: 400}[rate_hz]
    assert len(calls) == math.ceil((math.floor(0.301 * rate_hz) + 1) / chunk) and all(n == chunk for _, n in calls)


@pytest.mark.parametrize("faulty", [False, True])
def test_a_block_read_holds_what_the_records_hold(faulty):
    """``read_block`` (the loop's way in) and ``read`` give the same readings tick by tick, faults included
    (a dropout removes samples, a spike and a NaN change them)."""
    from hapticlab.core.types import WrenchBlock
    from hapticlab.plugins.simworld.faults import Fault

    faults = (
        (
            Fault("sensor_dropout", 0.3, 0.1),
            Fault("sensor_spike", 0.5, force=(5.0, 0.0, 0.0)),
            Fault("sensor_nan", 0.7, 0.05),
        )
        if faulty
        else ()
    )
    by_block, by_record = (SimSensor(rate_hz=7000.0, world=SimWorld(faults=faults)) for _ in range(2))
    by_block.open(T0)
    by_record.open(T0)
    rng = np.random.default_rng(4)
    now, blocks, records = T0, [], []
    while now < T0 + 999_999_999:
        now = min(now + int(rng.integers(0, 2_000_000)), T0 + 999_999_999)  # the first second's samples
        blocks.append(by_block.read_block(now))
        records += by_record.read(now)
    assert all(isinstance(b, WrenchBlock) for b in blocks)
    joined = [np.concatenate([getattr(b, k) for b in blocks]) for k in ("t_ns", "force_S", "torque_S", "seq", "status")]
    for got, want in zip(joined, as_arrays(records)):
        np.testing.assert_array_equal(got, want)
    assert len(joined[0]) == (6300 if faulty else 7000)  # 1 s at 7 kHz, less the 0.1 s dropout
    assert not faulty or np.isnan(joined[1]).any()


def test_a_bias_ramp_grows_then_holds_and_a_stuck_sensor_repeats_its_first_reading():
    """``sensor_bias_step`` with ``ramp``: force·min((t − start)/ramp, 1) added; ``sensor_stuck``: every reading
    of its window is the first one, across reads (the sensor is read in many small blocks)."""
    from hapticlab.plugins.simworld.faults import Fault

    ramp = Fault("sensor_bias_step", 0.2, force=(3.0, 0.0, 0.0), ramp=0.4)
    stuck = Fault("sensor_stuck", 0.7, 0.2)
    faulty, clean = (SimSensor(rate_hz=1000.0, world=SimWorld(faults=f)) for f in ((ramp, stuck), ()))
    for sensor in (faulty, clean):
        sensor.open(T0)
    got, want = [], []
    for k in range(1, 101):  # 1 s in 10 ms reads
        got += faulty.read(T0 + k * 10_000_000)
        want += clean.read(T0 + k * 10_000_000)
    t_f, f_f, tq_f, _, status = as_arrays(got)
    t_c, f_c, _, _, _ = as_arrays(want)
    np.testing.assert_array_equal(t_f, t_c)
    t = (t_f - T0) * 1e-9
    grown = np.clip((t - 0.2) / 0.4, 0.0, 1.0)
    free = t < 0.7 - 1e-9
    np.testing.assert_allclose(f_f[free] - f_c[free], np.outer(grown[free], [3.0, 0.0, 0.0]), atol=1e-12)
    held = (t >= 0.7 - 1e-9) & (t < 0.9 - 1e-9)
    assert held.sum() == 200 and (status == STATUS_OK).all()
    first = np.flatnonzero(held)[0]
    np.testing.assert_array_equal(f_f[held], np.broadcast_to(f_f[first], (200, 3)))  # across 20 reads
    np.testing.assert_array_equal(tq_f[held], np.broadcast_to(tq_f[first], (200, 3)))
    assert np.ptp(f_c[held], axis=0).max() > 0.01  # the world itself moved meanwhile
