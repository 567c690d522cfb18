"""The ``netft`` sensor and its emulator: pynetft reads the emulator, the plugin reads the simulated world through it.

Every test of the plugin runs with both receivers (the ``receiver`` fixture): ``hapticlab`` (our own,
``plugins/sensors/rdt.py``) and ``pynetft`` (the community client).

Every emulator serves on its own 127.0.0.x address with ports the kernel picks,
and is fed by the demo preset's world (seed 7): the counts on the wire are the
simulated physics, so each check compares against the world's reading at the
sample's own internal time. Loops wait for a number of samples, never a time.
"""

from __future__ import annotations

import itertools
import socket
import threading
import time
from contextlib import contextmanager

import numpy as np
import pynetft
import pytest

from hapticlab.core.host.interfaces import EmitsEvents, HasCalibration, HasRange, ReportsHealth, SensorSource
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.types import STATUS_DEVICE_ERROR, STATUS_OK, STATUS_SATURATED
from hapticlab.plugins.device_clock import DeviceClock
from hapticlab.plugins.sensors.netft import NetFTSensor
from hapticlab.plugins.sensors.netft_emulator import NetFTEmulator
from hapticlab.plugins.sensors.netft_protocol import FT_RATE_HZ, RECORD, REQUEST, describe_status, stream_status
from hapticlab.plugins.sensors.netft_wire import RdtFault
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.sessions.config import load_config
from hapticlab.sessions.recording import read_recording

COUNTS = 1_000_000.0  # the emulator's counts per N and per N·m
DEADLINE_S = 20.0  # a guard against hangs only: the loops end on sample counts


@pytest.fixture(params=["hapticlab", "pynetft"])
def receiver(request) -> str:
    """The plugin's RDT receiver: every plugin test runs with both."""
    return request.param


def demo_world(faults: list[dict] | None = None) -> SimWorld:
    table = dict(load_config("demo")[0]["world"])
    if faults:
        table["faults"] = faults
    return SimWorld.from_config(table)


def world_counts(emu: NetFTEmulator, world: SimWorld, ft_sequence: np.ndarray) -> np.ndarray:
    """(N, 6) the counts the emulated sensor reads at those internal samples (before any bias)."""
    t = np.array([emu.world_time(int(k)) for k in ft_sequence])
    reading = world.wrench(t)
    return emu.counts_of(reading["force_S"], reading["torque_S"])


def read_samples(sensor: NetFTSensor, count: int) -> list:
    samples, guard = [], time.monotonic() + DEADLINE_S
    while len(samples) < count and time.monotonic() < guard:
        samples += sensor.read(time.monotonic_ns())
        time.sleep(0.002)
    assert len(samples) >= count, f"only {len(samples)} samples"
    return samples


def until(condition) -> None:
    guard = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < guard, "the emulator never got there"
        time.sleep(0.002)


# ----------------------------------------------------------------------------- pynetft itself, on the emulator


def test_pynetft_reads_the_emulators_calibration_samples_and_bias(netft_emulator):
    world = demo_world()
    with netft_emulator(world, "127.0.0.131", 0, 0, counts_per_torque=1000.0, torque_unit="Nmm") as emu:
        config = pynetft.Config(sensor_host="127.0.0.131", rdt_port=emu.rdt_port, http_port=emu.http_port)
        with pynetft.Client(config, queue_size=10_000) as client:
            samples = [s for s, _ in zip(client.samples(timeout=5.0), range(500))]
            calibration = client.health().sensor_configuration
            client.bias()
            until(lambda: emu.counts.biases == 1)
            bias_ft = emu.bias_ft_sequence
            after = []
            for s in client.samples(timeout=5.0):
                if s.ft_sequence > bias_ft:
                    after.append(s)
                if len(after) == 200:
                    break
    assert calibration.product_name == "Net F/T emulator (hapticlab)"
    assert calibration.calibration == pynetft.Calibration(
        COUNTS, 1000.0, pynetft.ForceUnit.NEWTON, pynetft.TorqueUnit.NEWTON_MILLIMETER
    )
    raw = np.array([s.raw_wrench for s in samples])
    ft = np.array([s.ft_sequence for s in samples])
    # 7000 Hz: every internal sample is sent; a loaded machine may drop one on loopback before pynetft reads it
    assert (np.diff(ft) >= 1).all() and np.median(np.diff(ft)) == 1
    np.testing.assert_array_equal(raw, world_counts(emu, world, ft))
    force_N = np.array([s.force for s in samples])  # pynetft's scaling, in the sensor's unit (N)
    np.testing.assert_allclose(force_N, raw[:, :3] / COUNTS, rtol=1e-12)
    assert abs(raw).max() > 1000  # a reading, not zeros
    # the bias request: the reading at that moment is subtracted from every later record
    np.testing.assert_array_equal(emu.bias_counts, world_counts(emu, world, np.array([bias_ft]))[0])
    ft_after = np.array([s.ft_sequence for s in after])
    np.testing.assert_array_equal(
        np.array([s.raw_wrench for s in after]), world_counts(emu, world, ft_after) - emu.bias_counts
    )


def test_the_emulator_answers_a_counted_start_request_from_its_own_socket(netft_emulator):
    """RDT by hand: a start request for 5 records gets exactly 5, numbered 1..5, from the address asked."""
    with netft_emulator(demo_world(), "127.0.0.130", 0, 0, rdt_rate_hz=1000.0) as emu:
        client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        client.settimeout(5.0)
        try:
            client.sendto(REQUEST.pack(0x1234, 0x0002, 5), ("127.0.0.130", emu.rdt_port))
            records = [client.recvfrom(64) for _ in range(5)]
            client.settimeout(0.05)
            with pytest.raises(socket.timeout):  # and no sixth
                client.recvfrom(64)
            client.sendto(b"\x12\x34\x00", ("127.0.0.130", emu.rdt_port))  # too short: ignored
            until(lambda: emu.counts.ignored == 1)
        finally:
            client.close()
    assert {sender for _, sender in records} == {("127.0.0.130", emu.rdt_port)}
    fields = [RECORD.unpack(data) for data, _ in records]
    assert [f[0] for f in fields] == [1, 2, 3, 4, 5]
    assert all(b[1] - a[1] == 7 for a, b in itertools.pairwise(fields))  # 1 kHz: every 7th internal sample
    assert not emu.streaming


# ----------------------------------------------------------------------------- the plugin


def test_the_plugin_reads_the_simulated_wrench_to_one_count_at_the_devices_times(receiver, netft_emulator):
    """(The emulator runs in this process: a 1 s receive timeout keeps a pause of the machine under the full
    suite's load from counting as a timeout, which the default 0.1 s did once in a CI run here. The device's
    counter runs from the emulator's start, not the stream's: the wrap is 2 s in, and the test reads until it
    is 2 000 samples past it, because a CI run once took 0.3 s from the emulator's start to the first record.)"""
    world = demo_world()
    start = 2**32 - 2 * int(FT_RATE_HZ)  # the device counter wraps 2 s after the emulator starts sampling
    with netft_emulator(world, "127.0.0.132", 0, 0, ft_sequence_start=start) as emu:
        sensor = NetFTSensor("127.0.0.132", emu.rdt_port, emu.http_port, receiver=receiver, receive_timeout=1.0)
        assert isinstance(sensor, SensorSource) and isinstance(sensor, HasCalibration)
        assert isinstance(sensor, HasRange) and isinstance(sensor, EmitsEvents) and isinstance(sensor, ReportsHealth)
        sensor.open(time.monotonic_ns())
        samples = read_samples(sensor, 2000)
        assert samples[0].seq < 2**32, "the stream began after the wrap: the machine paused for 2 s"
        guard = time.monotonic() + DEADLINE_S
        while samples[-1].seq < 2**32 + 2000 and time.monotonic() < guard:
            samples += read_samples(sensor, 1)
        sensor.close()
    seq = np.array([s.seq for s in samples])
    assert seq[0] < 2**32 < seq[-1]  # unwrapped past the wrap
    assert (np.diff(seq) >= 1).all()  # 7000 Hz: every internal sample, but for what the loopback lost ...
    assert seq[-1] - seq[0] + 1 - len(seq) <= sensor.health_counters()["lost"]  # ... each one counted
    force_S = np.array([s.force_S for s in samples])
    torque_S = np.array([s.torque_S for s in samples])
    t_world = np.array([emu.world_time(int(k) % 2**32) for k in seq])
    truth = world.wrench(t_world)
    assert np.abs(force_S - truth["force_S"]).max() <= 0.5 / COUNTS + 1e-12  # within one count's rounding
    assert np.abs(torque_S - truth["torque_S"]).max() <= 0.5 / COUNTS + 1e-12
    assert np.abs(force_S - truth["force_S"]).max() > 0  # counts, not the floats themselves
    # times: the device's sample times on the session clock; never before the emulator sampled them
    t_ns = np.array([s.t_ns for s in samples])
    true_ns = emu.t0_ns + np.rint(t_world * 1e9).astype(np.int64)
    assert (np.diff(t_ns) > 0).all()
    assert (t_ns >= true_ns).all()
    assert np.median(t_ns - true_ns) < 0.1e9  # the mapping's scale is right (seconds off would be a bug)
    assert all(s.status == STATUS_OK for s in samples)
    calibration = sensor.calibration
    assert calibration["counts_per_force"] == "1e+06" and calibration["torque_unit"] == "N-m"
    kinds = [e.kind for e in sensor.drain_events()]
    assert kinds[0] == "sensor_calibration" and kinds[-1] == "sensor_health"
    assert "sensor_timeout" not in kinds


def test_wire_faults_show_in_the_health_counters_and_events(receiver, netft_emulator):
    """At 1 kHz (ft_sequence steps by 7), so the loopback's own buffer never overflows: every loss is injected.
    The emulator runs in this process: a receive timeout of 1 s (no injected fault silences the stream for more
    than a few ms) keeps a pause of the machine under the suite's load (the default 0.1 s tripped once in a
    full CI run) from counting as one; the check that no fault causes a timeout or a reconnect stays."""
    faults = [
        RdtFault("drop", 0.3, 0.1, every=3),
        RdtFault("duplicate", 0.45, 0.1, every=4),
        RdtFault("reorder", 0.6, 0.1, every=5),
        RdtFault("stall", 0.75, 0.1, every=6),
    ]  # apart
    with netft_emulator(demo_world(), "127.0.0.133", 0, 0, rdt_rate_hz=1000.0, faults=faults) as emu:
        sensor = NetFTSensor(
            "127.0.0.133",
            emu.rdt_port,
            emu.http_port,
            rate_hz=1000.0,
            health_interval=0.05,
            receiver=receiver,
            receive_timeout=1.0,
        )
        sensor.open(time.monotonic_ns())
        samples = read_samples(sensor, 10)
        until(lambda: emu.world_time(emu.last_ft_sequence) > 0.9)  # every fault window has passed
        samples += read_samples(sensor, 50)
        sensor.close()
    c = emu.counts
    assert c.dropped > 10 and c.duplicated > 10 and c.reordered > 10 and c.stalled > 10
    health = sensor.health_counters()
    assert health["duplicate"] == c.duplicated, (health, c)
    assert health["out_of_order"] == c.reordered, (health, c)
    if receiver == "pynetft":  # every late record is refused, and was counted lost at its gap
        late = c.reordered
        assert health["ft_backward"] == c.reordered, (health, c)
        assert health["stall"] == c.stalled + c.duplicated, (health, c)  # a duplicate repeats its ft_sequence too
    else:  # a late record is delivered in order when it comes in the same read as the later one, else it is late
        late = health["late"]
        assert late <= c.reordered and health["ft_backward"] == 0, (health, c)
        assert health["stall"] == c.stalled, (health, c)
    assert health["lost"] == c.dropped + late, (health, c)
    assert health["reconnect"] == health["timeout"] == 0
    seq = np.array([s.seq for s in samples])
    assert (np.diff(seq) > 0).all()  # no duplicate, late or stalled record reaches the stream
    assert (np.diff(seq) % 7 == 0).all()
    missing = int((seq[-1] - seq[0]) // 7 + 1 - len(seq))
    assert missing == c.dropped + late + c.stalled
    health_events = [e for e in sensor.drain_events() if e.kind == "sensor_health"]
    assert health_events[-1].data["lost"] == c.dropped + late
    assert any("stall +" in e.message for e in health_events)


def test_saturation_and_device_errors_reach_the_stream_as_status_bits_and_events(receiver, netft_emulator):
    faults = [RdtFault("saturate", 0.4, 0.02), RdtFault("status", 0.6, 0.02, status=0x8000_0008)]
    world = demo_world()
    with netft_emulator(world, "127.0.0.134", 0, 0, faults=faults) as emu:
        sensor = NetFTSensor("127.0.0.134", emu.rdt_port, emu.http_port, receiver=receiver)
        sensor.open(time.monotonic_ns())
        read_samples(sensor, 10)
        until(lambda: emu.world_time(emu.last_ft_sequence) > 0.8)
        samples = read_samples(sensor, 1)
        samples += read_samples(sensor, 300)
        sensor.close()
    status = np.array([s.status for s in samples])
    saturated = [s for s in samples if s.status & STATUS_SATURATED]
    assert saturated and (status & STATUS_DEVICE_ERROR).any()
    for s in saturated:  # every axis at its limit, with the reading's sign
        np.testing.assert_allclose(np.abs(s.force_S), world.sensor.saturation_force_S)
        np.testing.assert_allclose(np.abs(s.torque_S), world.sensor.saturation_torque_S)
    assert status[-1] == STATUS_OK  # and the stream goes on afterwards
    events = sensor.drain_events()
    kinds = [e.kind for e in events]
    assert "sensor_saturated" in kinds and "sensor_error" in kinds and "sensor_status_ok" in kinds
    error = next(e for e in events if e.kind == "sensor_error")
    assert error.data["status_word"] == 0x8000_0008 and "power monitor" in error.message


def test_a_saturated_record_does_not_interrupt_our_receivers_stream(netft_emulator):
    """hapticlab's receiver: the saturated records arrive, marked, and so does every record after them (1 kHz:
    the loopback never loses one), with no reconnect; pynetft would restart its stream here."""
    faults = [RdtFault("saturate", 0.4, 0.01)]
    with netft_emulator(demo_world(), "127.0.0.142", 0, 0, rdt_rate_hz=1000.0, faults=faults) as emu:
        sensor = NetFTSensor("127.0.0.142", emu.rdt_port, emu.http_port, rate_hz=1000.0)
        sensor.open(time.monotonic_ns())
        samples = read_samples(sensor, 10)
        until(lambda: emu.world_time(emu.last_ft_sequence) > 0.5)
        samples += read_samples(sensor, 50)
        sensor.close()
    seq = np.array([s.seq for s in samples])
    status = np.array([s.status for s in samples])
    saturated = np.flatnonzero(status & STATUS_SATURATED)
    assert len(saturated) == emu.counts.status >= 10  # 10 ms at 1 kHz, every one delivered
    assert (np.diff(seq) == 7).all()  # no gap anywhere: before, through and after the saturation
    assert (status[saturated[-1] + 1 :] == STATUS_OK).all() and len(status) > saturated[-1] + 40
    health = sensor.health_counters()
    assert health["reconnect"] == health["timeout"] == health["lost"] == 0
    assert health["device_error"] == len(saturated) and emu.counts.starts == 1


HAND_COUNTS = np.arange(6) * 1000 + 1000  # counts of a hand-made record i: HAND_COUNTS * i (1000 counts per unit)


def hand_records(rdt: list[int], ft: list[int] | None = None) -> bytes:
    """RDT records by hand, one datagram: rdt_sequence ``rdt``, ft_sequence ``ft`` (10 × rdt), status 0."""
    ft = [10 * r for r in rdt] if ft is None else ft
    return b"".join(RECORD.pack(r, f, 0, *(HAND_COUNTS * r).tolist()) for r, f in zip(rdt, ft))


@contextmanager
def hand_sensor(address: str):
    """Our receiver against a sensor played by hand: yields (plugin, send(datagram)); record 1 answers the start."""
    sensor_socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor_socket.bind((address, 0))
    sensor_socket.settimeout(5.0)
    client: list = []

    def answer_the_start():
        request, client[:] = sensor_socket.recvfrom(64)
        assert REQUEST.unpack(request) == (0x1234, 0x0002, 0)
        sensor_socket.sendto(hand_records([1]), tuple(client))

    answer = threading.Thread(target=answer_the_start)
    answer.start()
    try:
        sensor = NetFTSensor(
            address,
            sensor_socket.getsockname()[1],
            9,
            connect_timeout=2.0,  # no HTTP: override
            counts_per_force=1000.0,
            counts_per_torque=1000.0,
            force_unit="N",
            torque_unit="N-m",
        )
        sensor.open(time.monotonic_ns())
        answer.join()
        yield sensor, lambda datagram: sensor_socket.sendto(datagram, tuple(client))
        sensor.close()
    finally:
        sensor_socket.close()


def test_a_burst_of_records_between_two_reads_is_parsed_at_once():
    """After the first record, 70 more arrive before the next read (40 in one buffered-mode datagram, 30 one
    by one, a malformed datagram among them): one read, one drain and parse, all 71 in order."""
    with hand_sensor("127.0.0.141") as (sensor, send):
        drains = []
        drain = sensor._link.rdt.drain
        sensor._link.rdt.drain = lambda: drains.append(drain()) or drains[-1]
        send(hand_records(list(range(2, 42))))
        send(b"\x12" * 35)  # not a whole record: malformed, skipped
        for i in range(42, 72):
            send(hand_records([i]))
        samples = sensor.read(time.monotonic_ns() + 10**9)  # every sample parsed: their times end at the read's
    assert [len(d) for d in drains] == [71]  # one drain, one np.frombuffer for the whole tick
    assert [s.seq for s in samples] == [10 * i for i in range(1, 72)]
    np.testing.assert_allclose([s.force_S for s in samples], [HAND_COUNTS[:3] * i / 1000 for i in range(1, 72)])
    np.testing.assert_allclose([s.torque_S for s in samples], [HAND_COUNTS[3:] * i / 1000 for i in range(1, 72)])
    assert (np.diff([s.t_ns for s in samples]) > 0).all()
    health = sensor.health_counters()
    assert health["received"] == 71 and health["malformed"] == 1
    assert health["lost"] == health["duplicate"] == health["out_of_order"] == 0


def test_our_receiver_sorts_out_reorders_duplicates_late_records_and_a_restarted_sensor():
    """Each read by hand: what reaches the stream, and the counters (rdt.COUNTER_DOC)."""

    def read(*datagrams):
        for datagram in datagrams:
            send(datagram)
        return [s.seq for s in sensor.read(time.monotonic_ns() + 10**9)]

    with hand_sensor("127.0.0.143") as (sensor, send):
        assert read() == [10]
        assert read(hand_records([3, 2, 2, 5])) == [20, 30, 50]  # reordered in one read: sorted; 4 missing
        assert read(hand_records([4, 6, 3])) == [60]  # 4 late for its hole, 3 a duplicate
        assert read(hand_records([7, 8], [70, 70])) == [70]  # 8 repeats ft_sequence 70: a stall
        assert read(hand_records([9], [65])) == []  # ft_sequence back within a stream: refused
        assert read(hand_records([30], [300])) == [300]  # 10..29 lost
        events = sensor.drain_events()
        sensor._link.rdt.restart()  # as after a receive timeout: the start request again
        # the sensor had restarted (its counter too): the new stream numbers rdt_sequence from 1
        assert read(hand_records(list(range(1, 4)), [5, 6, 7])) == [301, 302, 303]
        health = sensor.health_counters()
    assert not any(e.kind == "sensor_restart" for e in events)
    assert [e.kind for e in sensor.drain_events()].count("sensor_restart") == 1
    assert health["received"] == 1 + 4 + 3 + 2 + 1 + 1 + 3
    assert health["out_of_order"] == 2  # 2 after 3, 4 after 5 (the second 2 and 3 are duplicates only)
    assert health["duplicate"] == 2 and health["late"] == 1  # rdt 4: lost, then late
    assert health["lost"] == 1 + 20
    assert health["stall"] == 1 and health["ft_backward"] == 1 and health["ft_restart"] == 1
    assert health["reconnect"] == 1


def test_a_read_holding_only_records_already_passed_delivers_nothing():
    """A read whose every record was passed already (a lone duplicate, a lone late record): counted, nothing
    delivered, the stream goes on (it raised an IndexError once: the faults test over the lab found it)."""

    def read(*datagrams):
        for datagram in datagrams:
            send(datagram)
        return [s.seq for s in sensor.read(time.monotonic_ns() + 10**9)]

    with hand_sensor("127.0.0.145") as (sensor, send):
        assert read() == [10]
        assert read(hand_records([3])) == [30]  # 2 missing
        assert read(hand_records([3])) == []  # a duplicate alone
        assert read(hand_records([2])) == []  # late alone
        assert read(hand_records([4])) == [40]
        health = sensor.health_counters()
    assert health["duplicate"] == 1 and health["late"] == 1 and health["lost"] == 1


def test_our_receiver_follows_a_stream_renumbered_by_a_start_request_still_in_flight():
    """After a timeout the start request goes again; records of the old numbering may come back first, then the
    request lands and the sensor numbers from 1 again: a new stream (same counter: no restart), not duplicates."""

    def read(datagram):
        send(datagram)
        return [s.seq for s in sensor.read(time.monotonic_ns() + 10**9)]

    with hand_sensor("127.0.0.144") as (sensor, send):
        assert read(hand_records(list(range(2, 41)))) == [10 * i for i in range(1, 41)]
        sensor._link.rdt.restart()
        assert read(hand_records([41, 42])) == [410, 420]  # the old numbering, back before the request landed
        assert read(hand_records([1, 2, 3], [430, 440, 450])) == [430, 440, 450]  # renumbered by it
        health = sensor.health_counters()
    assert health["duplicate"] == health["lost"] == health["ft_restart"] == 0
    assert not any(e.kind == "sensor_restart" for e in sensor.drain_events())


def test_datagrams_from_another_address_are_ignored(receiver, netft_emulator):
    world = demo_world()
    with netft_emulator(world, "127.0.0.135", 0, 0) as emu:
        sensor = NetFTSensor("127.0.0.135", emu.rdt_port, emu.http_port, receiver=receiver)
        sensor.open(time.monotonic_ns())
        read_samples(sensor, 10)
        forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        forger.bind(("127.0.0.136", 0))
        try:
            for i in range(200):  # plausible records, the next sequence numbers, absurd counts
                forger.sendto(
                    RECORD.pack(emu.rdt_sequence + 1 + i, emu.last_ft_sequence + 1 + i, 0, *[123_456_789] * 6),
                    emu.client,
                )
        finally:
            forger.close()
        samples = read_samples(sensor, 500)
        sensor.close()
    force_S = np.array([s.force_S for s in samples])
    assert np.abs(force_S).max() < 100.0  # not one forged 123 N reading
    health = sensor.health_counters()
    assert health["lost"] == health["out_of_order"] == health["duplicate"] == health["malformed"] == 0


def test_a_receive_timeout_zeroes_the_haptic_force_and_is_an_event(tmp_path, receiver, netft_emulator, paced_run):
    """A whole session on the emulator; 2000 records into the stream the cable is pulled for 0.3 s."""
    if receiver == "pynetft":  # its reconnect after a timeout makes these bounds timing-dependent under load
        pytest.skip(
            "pynetft reconnects after a timeout (new discovery, new stream): the session-level timing "
            "bounds here fail under CI load; its timeout and counters are covered at the plugin level"
        )
    from hapticlab.sessions.live.build import build_session

    config = load_config("demo")[0]
    with netft_emulator(SimWorld.from_config(config["world"]), "127.0.0.137", 0, 0) as emu:
        config["sensor"] = {
            "name": "netft",
            "address": "127.0.0.137",
            "rdt_port": emu.rdt_port,
            "http_port": emu.http_port,
            "receive_timeout": 0.05,
            "range_force": 65.0,
            "receiver": receiver,
        }
        config["session"] = dict(config["session"], duration=4.0, stale_timeout=0.02)  # 4 s: room for a slow machine
        session = build_session(config)
        assert session.device_events and session.device_events[0][0] == "sensor"

        def pull_the_cable():
            until(lambda: emu.counts.sent >= 2000)
            emu.mute()
            time.sleep(0.3)
            emu.mute(False)

        cable = threading.Thread(target=pull_the_cable)
        cable.start()
        result = paced_run(session, tmp_path / "netft.mcap")
        cable.join()
    muted_ns, unmuted_ns = emu.muted_ns
    assert unmuted_ns < result.events[-1].t_ns  # the stream came back within the session
    events = {e.kind: e for e in reversed(result.events)}  # the first of each kind
    timeout = events["sensor_timeout"]
    assert timeout.data["source"] == "sensor"
    assert muted_ns < timeout.t_ns < unmuted_ns
    # every haptic command from 20 ms (the stale timeout) + 5 ms after the cable was pulled until it is back:
    # zero, "no sensor data"
    commands = read_recording(tmp_path / "netft.mcap").topics["/haptic/command"]
    during = [m for t, m in commands if muted_ns + 0.025e9 <= t <= unmuted_ns]
    assert len(during) > 100
    assert all(not m["enabled"] and m["reason"] == "no sensor data" and m["force_D"] == [0.0, 0.0, 0.0] for m in during)
    assert events["sensor_resumed"].t_ns > unmuted_ns
    assert result.samples > 2000


# ----------------------------------------------------------------------------- config, status, clock, CLI


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"rdt_port": 70000}, "rdt_port"),
        ({"address": " "}, "address"),
        ({"receive_timeout": 0.0}, "receive_timeout"),
        ({"rate_hz": 8000.0}, "rate_hz"),
        ({"counts_per_force": 1e6}, "counts_per_torque"),
        (
            {"counts_per_force": 1e6, "counts_per_torque": -1.0, "force_unit": "N", "torque_unit": "N-m"},
            "counts_per_torque",
        ),
        (
            {"counts_per_force": 1e6, "counts_per_torque": 1e6, "force_unit": "stone", "torque_unit": "N-m"},
            "force_unit",
        ),
        ({"recovery": "pray"}, "recovery"),
        ({"range_force": [1.0, 2.0]}, "range_force"),
        ({"rdt_port": "49152"}, "rdt_port"),
        ({"bogus": 1}, "bogus"),
        ({"receiver": "libnetft"}, "receiver"),
    ],
)
def test_a_bad_config_is_one_line_naming_the_key(options, key, receiver):
    with pytest.raises(ConfigError) as err:
        Registry().create("sensor", "netft", {**options, "receiver": options.get("receiver", receiver)}, where="sensor")
    message = str(err.value)
    assert message.startswith(f"sensor.{key}:") and "\n" not in message


def test_no_sensor_is_a_clear_error_at_open(receiver):
    sensor = NetFTSensor("127.0.0.138", 9, 9, connect_timeout=0.3, receiver=receiver)  # nothing listens there
    with pytest.raises(ConnectionError, match=r"no Net F/T record from 127.0.0.138:9"):
        sensor.open(time.monotonic_ns())


def test_the_calibration_override_replaces_the_sensors(receiver, netft_emulator):
    world = demo_world()
    with netft_emulator(
        world, "127.0.0.139", 0, 0, counts_per_force=1000.0, counts_per_torque=1000.0, force_unit="N", torque_unit="Nm"
    ) as emu:
        sensor = NetFTSensor(
            "127.0.0.139",
            emu.rdt_port,
            emu.http_port,
            counts_per_force=2000.0,
            counts_per_torque=1.0,
            force_unit="N",
            torque_unit="N-mm",
            receiver=receiver,
        )
        sensor.open(time.monotonic_ns())
        samples = read_samples(sensor, 200)
        sensor.close()
    seq = np.array([s.seq for s in samples])
    truth = world.wrench(np.array([emu.world_time(int(k)) for k in seq]))
    np.testing.assert_allclose([s.force_S for s in samples], truth["force_S"] / 2, atol=0.5 / 2000 + 1e-12)
    np.testing.assert_allclose([s.torque_S for s in samples], truth["torque_S"], atol=0.5 / 1000 + 1e-12)
    assert sensor.calibration["source"] == "override" and sensor.calibration["torque_unit"] == "N-mm"


def test_the_status_word_maps_onto_the_streams_bits():
    assert stream_status(0) == STATUS_OK
    assert stream_status(0x8002_0000) == STATUS_SATURATED
    assert stream_status(0x8001_0000) == STATUS_OK  # a latched threshold monitor: the reading is good
    assert stream_status(0x8000_0000) == STATUS_DEVICE_ERROR
    assert stream_status(0x8000_0004) == STATUS_DEVICE_ERROR
    assert stream_status(0x8002_0004) == STATUS_SATURATED | STATUS_DEVICE_ERROR
    assert describe_status(0x8002_0004) == "transducer saturation or A/D error, internal temperature error"
    assert describe_status(0) == "healthy"


def test_the_device_clock_follows_the_fastest_packets_and_a_drifting_crystal():
    rng = np.random.default_rng(3)
    k = np.arange(70_000)  # 10 s at 7 kHz
    drift = 60e-6  # the device's crystal 60 ppm fast against the host's
    true_ns = 5e9 + k * (1e9 / 7000) / (1 + drift)
    latency_ns = 30_000 + rng.exponential(200_000, len(k))  # ≥ 30 µs, often much more
    received = np.rint(true_ns + latency_ns).astype(np.int64)
    clock = DeviceClock(7000.0, slew_ppm=200.0)
    t = np.array([clock.stamp(int(i), int(r)) for i, r in zip(k, received)])
    assert (np.diff(t) > 0).all() and (t <= received).all()
    error_ns = t - true_ns
    assert error_ns[7000:].min() >= 30_000 - 1  # never before the fastest packet allows
    assert error_ns[7000:].max() < 60_000  # within 30 µs of the latency floor after the first second
    assert np.percentile(latency_ns, 50) > 150_000  # stamping by receipt would be off by this much
    batch_clock = DeviceClock(7000.0, slew_ppm=200.0)  # the same stamps a batch at a time
    batched = np.concatenate([batch_clock.stamp_many(k[i : i + 7], received[i : i + 7]) for i in range(0, len(k), 7)])
    assert np.abs(batched - t).max() <= 1


def test_a_wire_fault_parses_from_the_command_line():
    assert RdtFault.parse("status,start=1,duration=0.5,status=0x80020000") == RdtFault(
        "status", 1.0, 0.5, status=0x8002_0000
    )
    assert RdtFault.parse("drop,every=3") == RdtFault("drop", every=3)
    with pytest.raises(ValueError, match=r"^fault 'explode': kind: must be 'drop', 'duplicate', "):
        RdtFault.parse("explode")


def test_the_emulator_command_prints_its_address_and_ports_first(capsys):
    from hapticlab.sessions.cli import main

    argv = ["emulate", "netft", "--address", "127.0.0.140", "--rdt-port", "0", "--http-port", "0"]
    assert main([*argv, "--duration", "0.2", "--fault", "drop,every=2"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("netft emulator on 127.0.0.140: RDT udp/") and "http/" in first


def test_one_record_numbered_or_sampled_far_ahead_is_dropped_and_the_stream_goes_on():
    """A damaged record: its rdt_sequence 2³⁰ ahead (the stream would have taken every later record for a
    duplicate), or its ft_sequence 2³⁰ ahead (every later sample for one going back): counted corrupt, dropped."""

    def read(*datagrams):
        for datagram in datagrams:
            send(datagram)
        return [s.seq for s in sensor.read(time.monotonic_ns() + 10**9)]

    with hand_sensor("127.0.0.146") as (sensor, send):
        assert read() == [10]
        far = RECORD.pack(2 + 2**30, 30, 0, *[0] * 6)  # numbered far ahead (its counts zero: they do not matter)
        assert read(hand_records([2]) + far + hand_records([3])) == [20, 30]
        assert read(hand_records([4, 5], [40, 50 + 2**30])) == [40]  # sampled far ahead (the usual fast path)
        assert read(hand_records([6, 7], [60, 70])) == [60, 70]
        assert read(hand_records([8, 9, 10], [80, 90 + 2**30, 100])) == [80, 100]  # within one read
        health = sensor.health_counters()
    assert health["corrupt"] == 3 and health["lost"] == 0 and health["duplicate"] == 0
    assert health["stall"] == health["ft_backward"] == health["out_of_order"] == health["late"] == 0
