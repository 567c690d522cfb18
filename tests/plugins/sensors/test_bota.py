"""The ``bota`` sensor and its emulator over real pseudo-terminals; Bota's own driver (``bota-driver``) on the
emulator; a paced session on ``hapticlab emulate bota`` with faults.

The emulator is fed by the demo preset's world (seed 7): each frame's wrench is the world's reading at the
frame's own time, so the checks compare against it. Loops wait for a number of samples, never a time.
"""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
from processes import hapticlab_command

from hapticlab.core.types import STATUS_OK, STATUS_SATURATED
from hapticlab.plugins.sensors import bota_protocol as bp
from hapticlab.plugins.sensors.bota import BotaSensor
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.recording import read_recording

DEADLINE_S = 20.0  # a guard against hangs only: the loops end on sample counts


def demo_world() -> SimWorld:
    return SimWorld.from_config(dict(load_config("demo")[0]["world"]))


def read_samples(sensor: BotaSensor, count: int):
    blocks, n, guard = [], 0, time.monotonic() + DEADLINE_S
    while n < count and time.monotonic() < guard:
        block = sensor.read_block(time.monotonic_ns())
        blocks.append(block)
        n += len(block)
        time.sleep(0.002)
    assert n >= count, f"only {n} samples"
    return blocks


def until(condition) -> None:
    guard = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < guard, "never got there"
        time.sleep(0.002)


def test_the_plugin_sets_the_rate_and_reads_the_worlds_wrench_at_the_frames_times(bota_emulator):
    world = demo_world()
    with bota_emulator(world) as emu:  # powers on streaming at 800 Hz
        sensor = BotaSensor(emu.port, rate_hz=400.0)
        sensor.open(time.monotonic_ns())
        try:
            assert emu.sinc_length == 128 and emu.running and bytes(emu.received) == b"Cc,0,1,0,4f,128,0,0,1R"
            blocks = read_samples(sensor, 400)
        finally:
            sensor.close()
        until(lambda: not emu.running)  # close() puts it back in configuration mode
    seq = np.concatenate([b.seq for b in blocks])
    force = np.concatenate([b.force_S for b in blocks])
    torque = np.concatenate([b.torque_S for b in blocks])
    t_ns = np.concatenate([b.t_ns for b in blocks])
    assert (np.diff(seq) == 1).all()  # every frame of the run, in order
    reading = world.wrench(emu.world_time(emu.run_timestamps_us(np.arange(len(seq)))))  # from the first frame on
    np.testing.assert_array_equal(force, reading["force_S"].astype(np.float32))
    np.testing.assert_array_equal(torque, reading["torque_S"].astype(np.float32))
    # the sensor's own spacing, up to the device clock's slew (200 ppm) and a step back to a faster receipt
    steps = np.diff(t_ns)
    assert (steps > 0).all() and 2_500_000 <= np.median(steps) <= 2_500_000 * (1 + 200e-6) + 1
    assert sensor.health_counters()["crc_errors"] == 0 and 28.0 <= sensor.temperature_C < 28.1


def test_wire_faults_are_counted_flagged_and_a_pulled_cable_is_one_line(bota_emulator):
    with bota_emulator(demo_world()) as emu:
        sensor = BotaSensor(emu.port, receive_timeout=0.1)
        sensor.open(time.monotonic_ns())
        read_samples(sensor, 50)
        emu.corrupt_frames(3)
        emu.garbage(os.urandom(40).replace(b"\xaa", b"\x55"))  # line noise: no header in it
        blocks = read_samples(sensor, 100)
        emu.set_status(bp.STATUS_OVERRANGE, 0.05)
        blocks += read_samples(sensor, 100)
        emu.stall(0.3)
        stalled = time.monotonic()
        while time.monotonic() - stalled < 0.35:  # read on as a session does: the silence is seen
            blocks.append(sensor.read_block(time.monotonic_ns()))
            time.sleep(0.002)
        blocks += read_samples(sensor, 50)
        counters = sensor.health_counters()
        events = sensor.drain_events()
        emu.unplug()
        with pytest.raises(ConnectionError, match=r"^Bota sensor /dev/pts/\d+: the port (failed|hung up).*unplugged"):
            until(lambda: sensor.read_block(time.monotonic_ns()) is None)
        sensor.close()
    # a broken frame is one CRC error at its header, and one more at each 0xAA in its data the search meets
    assert counters["crc_errors"] >= 3 and counters["skipped_bytes"] >= 40
    assert counters["lost"] == 3 + emu.counts.stalled_frames  # the broken frames, then the stalled ones
    status = np.concatenate([b.status for b in blocks])
    assert (status == STATUS_SATURATED).sum() == emu.counts.status_frames > 0
    assert set(status.tolist()) == {STATUS_OK, STATUS_SATURATED}
    kinds = [e.kind for e in events]
    for kind in ("sensor_saturated", "sensor_status_ok", "sensor_timeout", "sensor_resumed", "sensor_temperature"):
        assert kind in kinds, kind


def test_a_port_with_no_sensor_or_held_by_another_is_one_line_naming_it(pty_pair, bota_emulator):
    _, slave = pty_pair
    with pytest.raises(ConnectionError, match=r"no answer to 'C' within 0.3 s \(no bytes at all"):
        BotaSensor(os.ttyname(slave), open_timeout=0.3).open(0)
    with bota_emulator(demo_world()) as emu:
        first = BotaSensor(emu.port)
        first.open(0)
        try:
            with pytest.raises(ConnectionError, match="held by another program"):
                BotaSensor(emu.port).open(0)
        finally:
            first.close()


def emulator_process(spawn_process, *args: str):
    proc = spawn_process(hapticlab_command("emulate", "bota", *args), "emulate bota")
    port = proc.first_line().strip()
    assert port.startswith("/dev/pts/"), port
    proc.next_line()  # what it serves
    return proc, port


def test_botas_own_driver_reads_the_emulator_once_told_not_to_ask_for_metadata(spawn_process):
    """bota-driver 1.1.16 (Bota_Binary_gen0) sends C, c,0,1,0,4, f,64,0,0,1, s and R, each ending in a newline,
    and reads the frames; by default it first asks for the sensor's metadata (``p?``), which Bota does not
    document and the emulator does not answer: configure() then fails."""
    bd = pytest.importorskip("bota_driver")
    proc, port = emulator_process(spawn_process, "--duration", "60")

    def driver(skip_metadata: bool):
        config = bd.BotaDriverConfig()
        config.product_name, config.serial_number = "BFT-SENS-SER-M8", "SN000000"
        config.communication_interface_name = "Bota_Binary_gen0"
        serial = bd.BotaBinaryCommunicationInterfaceConfig()
        serial.com_port, serial.baudrate = port, 460800
        config.binary_communication_interface_params = serial
        operation = bd.Gen0SensorOperationConfig()
        operation.sinc_length = 64
        config.gen0_sensor_operation_params = operation
        options = bd.DriverOperationConfig()
        options.skip_metadata_reading, options.runtime_verbosity = skip_metadata, False
        config.driver_operation_params = options
        return bd.BotaDriver(config)

    with pytest.raises(RuntimeError, match="Failed to read sensor metadata"):
        driver(skip_metadata=False)
    bota = driver(skip_metadata=True)
    assert bota.configure() and bota.activate()
    frames = [bota.read_frame_blocking() for _ in range(800)]
    assert bota.get_expected_timestep_us() == 1250
    bota.deactivate()
    bota.shutdown()
    last = proc.finish().strip().splitlines()[-1]
    run_ns = int(last.rsplit("run_after_boot_ns=", 1)[1])
    timestamp = np.array([f.timestamp for f in frames], dtype=np.int64)
    assert (np.diff(timestamp) % 2**32 == 1250).mean() > 0.99  # the driver drops none but a slow read's
    t = np.maximum(0.0, timestamp * 1e-6 - run_ns * 1e-9)  # the emulator's world time of each frame
    reading = demo_world().wrench(t)
    np.testing.assert_array_equal(np.array([f.force for f in frames]), reading["force_S"].astype(np.float32))
    np.testing.assert_array_equal(np.array([f.torque for f in frames]), reading["torque_S"].astype(np.float32))
    assert all(28.0 <= f.temperature < 28.1 for f in frames)


def test_a_session_on_the_emulator_reads_the_stream_and_feels_the_worlds_contact(tmp_path, spawn_process, paced_run):
    """12 s at 800 Hz with a broken CRC, a 0.3 s stall and 50 ms of overrange on the wire: every other frame
    recorded, the force zero while the data is bad, the compensated contact force within the world's."""
    faults = ("--fault", "crc@3:5", "--fault", "stall@4:0.3", "--fault", "overrange@5:0.05")  # world times
    proc, port = emulator_process(spawn_process, "--duration", "120", *faults)
    config, _ = load_config("demo")
    config = apply_overrides(
        config, ["sensor.name=bota", f"sensor.port={port}", "sensor.rate_hz=800", "session.duration=12"]
    )
    del config["shadows"]
    result = paced_run(build_session(config), tmp_path / "bota.mcap")
    said = proc.finish()
    stalled = int(said.rsplit(" stalled", 1)[0].rsplit(", ", 1)[1])
    rec = read_recording(result.path)
    seq = rec.field("/sensor/wrench", "seq").astype(np.int64)
    health = [e for e in rec.events if e.kind == "sensor_health"][-1].data
    assert health["crc_errors"] >= 5 and health["lost"] == seq[-1] - seq[0] + 1 - len(seq)
    assert len(seq) + health["lost"] >= 0.99 * 800 * 12  # the stream at its rate over the session
    assert 200 < stalled < 300 and health["lost"] == 5 + stalled  # every frame sent was read but the broken ones
    assert result.samples == len(seq)
    kinds = [e.kind for e in rec.events]
    for kind in ("sensor_timeout", "sensor_resumed", "sensor_saturated", "sensor_status_ok"):
        assert kind in kinds, kind
    reasons = {e.data.get("reason", e.message) for e in rec.events if e.kind == "haptic_disabled"}
    assert any("saturated" in r for r in reasons) and any("no sensor data" in r for r in reasons), reasons
    temperature = [e.data["temperature_C"] for e in rec.events if e.kind == "sensor_temperature"]
    assert len(temperature) >= 10 and temperature == sorted(temperature)  # warming up

    t_ns = rec.t_ns("/estimator/kalman")
    wrench_t = rec.t_ns("/sensor/wrench")
    world_t = (seq[np.searchsorted(wrench_t, t_ns)] - seq[0]) / 800.0  # the first frame is the world's t = 0
    truth = demo_world().wrench(world_t, noise=False)["contact_force_S"]
    estimated = rec.field("/estimator/kalman", "contact_force_S")
    after = rec.field("/estimator/kalman", "converged_force").astype(bool) & (world_t > 2.0)
    error = np.linalg.norm(estimated[after] - truth[after], axis=1)
    assert after.sum() > 0.7 * len(after) and np.sqrt((error**2).mean()) < 0.3  # the noise is 0.21 N in norm
    pressing = after & (np.linalg.norm(truth, axis=1) > 1.5)
    assert pressing.sum() > 500
    assert np.abs(np.linalg.norm(estimated[pressing], axis=1) - np.linalg.norm(truth[pressing], axis=1)).mean() < 0.3
