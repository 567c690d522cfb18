"""The ``robotiq_ft300`` sensor against the FT 300 emulator over real pseudo-terminals (the realtime tier):
a Modbus client library reads the emulator as it would the sensor, the plugin delivers only good frames
through CRC errors, garbage and a stall, reports a disconnect in one event, and a paced session on
``hapticlab emulate robotiq-ft300`` reads the 100 Hz stream and feels the contact the world made."""

from __future__ import annotations

import time

import minimalmodbus
import numpy as np
import pytest
from processes import hapticlab_command

from hapticlab.plugins.sensors import robotiq_protocol as rq
from hapticlab.plugins.sensors.robotiq_emulator import ScheduledFault
from hapticlab.plugins.sensors.robotiq_ft300 import RobotiqFT300Sensor
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.config import load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.recording import read_recording


@pytest.fixture(scope="module")
def world() -> SimWorld:
    config, _ = load_config("demo")
    return SimWorld.from_config(config["world"])


def read_for(sensor: RobotiqFT300Sensor, seconds: float) -> tuple[np.ndarray, ...]:
    """Read the sensor once a millisecond for ``seconds``: (t_ns, seq, counts) of what it delivered."""
    blocks = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        block = sensor.read_block(time.monotonic_ns())
        if len(block):
            blocks.append(block)
        time.sleep(0.001)
    t_ns = np.concatenate([b.t_ns for b in blocks])
    seq = np.concatenate([b.seq for b in blocks])
    wrench = np.concatenate([np.hstack([b.force_S, b.torque_S]) for b in blocks])
    return t_ns, seq, np.rint(wrench / rq.SI_PER_COUNT).astype(np.int64)


def test_minimalmodbus_reads_the_emulator_as_it_would_the_sensor(world, ft300_emulator):
    with ft300_emulator(world, serial_number="FTS-0042", production_year=2025) as emu:
        client = minimalmodbus.Instrument(emu.port, rq.SLAVE_ID)
        client.serial.baudrate, client.serial.timeout = rq.BAUDRATE, 0.5
        try:
            assert rq.serial_number(client.read_registers(rq.REG_SERIAL, 4)) == "FTS-0042"
            assert rq.firmware_version(client.read_registers(rq.REG_FIRMWARE, 3)) == "FTS-3.0.4"
            assert client.read_register(rq.REG_YEAR) == 2025
            time.sleep(0.05)
            forces = client.read_registers(rq.REG_FORCE, 6)  # the newest reading, signed 16-bit
            with pytest.raises(minimalmodbus.IllegalRequestError):  # no register 300: exception 02
                client.read_register(300)
        finally:
            client.serial.close()
        at = emu.world_time()
    reading = world.wrench(np.array([at]), noise=False)
    expected = np.concatenate([reading["force_S"][0], reading["torque_S"][0]]) / rq.SI_PER_COUNT
    signed = np.array([v - 65536 if v >= 32768 else v for v in forces])
    assert np.all(np.abs(signed - expected) * rq.SI_PER_COUNT <= [1.0] * 3 + [0.1] * 3)  # the world, within noise


def test_only_good_frames_reach_the_stream_through_crc_errors_garbage_and_a_stall(world, ft300_emulator):
    faults = [ScheduledFault("crc", 0.6, 3), ScheduledFault("garbage", 0.9, 200), ScheduledFault("stall", 1.2, 0.4)]
    with ft300_emulator(world, faults=faults) as emu:
        sensor = RobotiqFT300Sensor(port=emu.port)
        sensor.open(time.monotonic_ns())
        t_ns, seq, counts = read_for(sensor, 2.5)
        sensor.close()
        sent = list(emu.sent)
        t0_ns = emu.t0_ns
    # every delivered frame is one the emulator sent with a good CRC, in order, none left out but the last unread
    good = [(index, row) for index, row, broken in sent if not broken]
    assert len(counts) >= len(good) - 2 and np.array_equal(counts, np.array([row for _, row in good[: len(counts)]]))
    assert sum(broken for *_, broken in sent) == 3
    health = sensor.health_counters()
    assert health["crc_errors"] == 3 and health["garbage_bytes"] >= 200 and health["timeouts"] >= 1
    # the sequence numbers: one gap per broken frame (the stream has no counter: a stall leaves none)
    index = np.array([i for i, _ in good[: len(counts)]])
    broken = np.array([i for i, _, bad in sent if bad])
    missing = sorted(set(range(int(seq[0]), int(seq[-1]) + 1)) - set(seq.tolist()))
    assert missing == (seq[0] + broken - index[0]).tolist() and len(missing) == 3  # before the stall, in slots
    # the stall held back its 0.4 s of frames (more when the loaded machine starves the emulator: its own count),
    # and the stamps jump with them, by the sensor's 10 ms spacing (what the stream says, not the wall clock)
    stall = int(np.argmax(np.diff(index)))
    gap = int(np.diff(index)[stall])
    assert gap >= 40 and health["stalls"] >= 1
    assert round(np.diff(t_ns)[stall] * 1e-7) == gap
    # stamped from each frame's sample time on, never before it
    delay_ms = (t_ns - t0_ns - index * 1e7) * 1e-6
    assert delay_ms.min() >= 0 and np.all(np.diff(t_ns) > 0)
    kinds = [e.kind for e in sensor.drain_events()]
    assert kinds[0] == "sensor_connected" and "sensor_timeout" in kinds and "sensor_resumed" in kinds


def test_a_disconnect_is_one_event_naming_the_port_and_the_stream_goes_quiet(world, ft300_emulator):
    with ft300_emulator(world, faults=[ScheduledFault("unplug", 0.5)]) as emu:
        # no second try within the test: a pty's number is soon another program's
        sensor = RobotiqFT300Sensor(port=emu.port, reconnect_interval=60.0)
        sensor.open(time.monotonic_ns())
        t_ns, _, _ = read_for(sensor, 1.0)  # reads on after the unplug: nothing, and no exception
    events = sensor.drain_events()
    lost = [e for e in events if e.kind == "sensor_disconnected"]
    assert len(lost) == 1 and emu.port in lost[0].message and "Input/output error" in lost[0].message
    assert 35 <= len(t_ns) <= 55 and sensor.health_counters()["disconnects"] == 1  # ~0.4 s of frames, then none
    sensor.close()


def test_a_paced_session_on_the_emulator_reads_the_stream_and_feels_the_worlds_contact(
    tmp_path, spawn_process, paced_run
):
    emulator = spawn_process(
        hapticlab_command("emulate", "robotiq-ft300", "--session", "demo", "--duration", "200"), "emulate robotiq-ft300"
    )
    port = emulator.first_line().strip()
    assert port.startswith("/dev/pts/"), port
    config, _ = load_config("demo")
    config["sensor"] = {"name": "robotiq_ft300", "port": port}
    config["session"]["duration"] = 30.0
    result = paced_run(build_session(config), tmp_path / "ft300.mcap")
    emulator.finish()
    rec = read_recording(result.path)

    # the 100 Hz stream for 30 s: at least 99 % of its 3000 frames, gap-free (the first ~0.1 s is the open)
    seq = rec.field("/sensor/wrench", "seq").astype(np.int64)
    assert len(seq) == result.samples >= 0.99 * 3000 and np.all(np.diff(seq) == 1)
    assert rec.metadata["hapticlab.calibration"]["serial_number"] == "FTS-4242"
    # the compensated contact force against the world's contact, once converged (the session's world time:
    # its kinematics'; the emulator's world starts at the session's first byte, a few ms later)
    t0_ns = next(e.t_ns for e in rec.events if e.kind == "session_start")
    world_t = (rec.t_ns("/estimator/kalman") - t0_ns) * 1e-9
    estimated = rec.field("/estimator/kalman", "contact_force_S")
    converged = rec.field("/estimator/kalman", "converged_force").astype(bool)
    truth = SimWorld.from_config(config["world"]).wrench(world_t, noise=False)["contact_force_S"]
    after = converged & (world_t > world_t[np.argmax(converged)] + 1.0)
    assert after.sum() > 2000
    error = np.linalg.norm(estimated[after] - truth[after], axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.3  # N; the world's sensor noise is 0.12 N per axis (0.21 N in norm)
    pressing = after & (np.linalg.norm(truth, axis=1) > 1.5)  # the indentations' plateaus at 3, 2 and 4 N
    assert pressing.sum() > 100
    assert np.abs(np.linalg.norm(estimated[pressing], axis=1) - np.linalg.norm(truth[pressing], axis=1)).mean() < 0.3
