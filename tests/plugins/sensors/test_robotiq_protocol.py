"""The Robotiq FT 300's wire, without a port: CRC, frames, the stream parser's resynchronisation, register
encodings, and the emulator's Modbus answers and frames (fed and read in memory)."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.host.options import OptionError
from hapticlab.plugins.sensors import robotiq_protocol as rq
from hapticlab.plugins.sensors.robotiq_emulator import FT300Emulator, ScheduledFault
from hapticlab.plugins.sensors.robotiq_ft300 import RobotiqFT300Sensor
from hapticlab.plugins.sensors.robotiq_link import start_request
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.config import load_config


@pytest.fixture(scope="module")
def world() -> SimWorld:
    config, _ = load_config("demo")
    return SimWorld.from_config(config["world"])


def world_counts(world: SimWorld, n: int = 200) -> np.ndarray:
    """(n, 6) counts of the demo world's readings at 100 Hz (noise, motion and contacts from seed 7)."""
    reading = world.wrench(np.arange(n) * 0.01 + 5.0)  # from 5 s: the first indentation comes at 6 s
    return rq.counts_of(reading["force_S"], reading["torque_S"])


def stream(counts: np.ndarray) -> bytes:
    return b"".join(rq.encode_frame(row) for row in counts)


def test_the_crc_and_the_start_request_are_the_manuals():
    # the manual's FC03 example reads Fx (register 180) of slave 9: 09 03 00 B4 00 01, CRC bytes C5 64
    assert rq.with_crc(bytes.fromhex("090300b40001"))[-2:] == bytes.fromhex("c564")
    # 0x0200 to register 410 as Robotiq's driver and the community clients send it: CRC bytes CD CA
    assert start_request() == bytes.fromhex("0910019a0001020200cdca")
    assert rq.crc16(b"123456789") == 0x4B37  # the CRC-16/MODBUS check value


def test_frames_of_the_simulated_world_parse_back_however_the_port_cuts_them(world):
    counts = world_counts(world)
    data = stream(counts)
    parser = rq.StreamParser()
    rng = np.random.default_rng(3)
    cuts = np.sort(rng.choice(np.arange(1, len(data)), size=150, replace=False))
    values, slots = [], []
    for chunk in np.split(np.frombuffer(data, np.uint8), cuts):
        v, s = parser.feed(chunk.tobytes())
        values += v
        slots += s
    assert np.array_equal(np.array(values), counts) and slots == list(range(len(counts)))
    assert parser.crc_errors == 0 and parser.garbage_bytes == 0
    # the quantisation is the wire's: 1/100 N and 1/1000 N·m
    reading = world.wrench(np.arange(len(counts)) * 0.01 + 5.0)
    wrench = np.array(values) * rq.SI_PER_COUNT
    assert np.abs(wrench[:, :3] - reading["force_S"]).max() <= 0.005 + 1e-9
    assert np.abs(wrench[:, 3:] - reading["torque_S"]).max() <= 0.0005 + 1e-9


def test_a_damaged_frame_is_dropped_counted_and_leaves_its_slot_empty(world):
    counts = world_counts(world, 20)
    data = bytearray(stream(counts))
    data[7 * rq.FRAME_SIZE + 5] ^= 0x10  # a bit of frame 7's Fy flipped on the wire
    data[12 * rq.FRAME_SIZE + 14] ^= 0x01  # frame 12's CRC itself
    parser = rq.StreamParser()
    values, slots = parser.feed(bytes(data))
    assert parser.crc_errors == 2 and parser.garbage_bytes == 0
    assert slots == [i for i in range(20) if i not in (7, 12)]
    assert np.array_equal(np.array(values), np.delete(counts, [7, 12], axis=0))  # no damaged value delivered


def test_the_stream_resynchronises_on_the_header_after_garbage(world):
    counts = world_counts(world, 30)
    frames = [rq.encode_frame(row) for row in counts]
    # a Modbus echo before the stream, line noise holding a false header, and a frame cut short
    garbage = bytes.fromhex("0910019a0001") + b"\x20\x4e\x00\x01\x02" + bytes(range(40))
    data = garbage + b"".join(frames[:10]) + frames[10][:9] + b"".join(frames[11:])
    parser = rq.StreamParser()
    values, _ = parser.feed(data)
    assert np.array_equal(np.array(values), np.delete(counts, [10], axis=0))
    assert parser.frames == 29 and parser.garbage_bytes == len(garbage) + 9


def test_readings_beyond_the_wire_clip_and_a_missing_one_is_zero():
    counts = rq.counts_of(np.array([[400.0, -400.0, np.nan]]), np.array([[40.0, 0.0015, -0.0015]]))
    assert counts.tolist() == [[32767, -32767, 0, 32767, 2, -2]]


def test_serial_number_and_firmware_read_as_robotiqs_driver_writes_them():
    registers = rq.serial_number_registers("FTS-0042")
    assert registers[:2] == [0x4654, 0x5300] and rq.serial_number(registers) == "FTS-0042"
    assert rq.serial_number(rq.serial_number_registers("FTS-70000")) == "FTS-70000"  # past one register
    assert rq.firmware_version(rq.text_registers("FTS", (3, 0, 4))) == "FTS-3.0.4"
    with pytest.raises(ValueError, match="three letters"):
        rq.serial_number_registers("42")


class Wire(FT300Emulator):
    """The emulator without a pty: what it writes is collected."""

    def __init__(self, world, **kwargs):
        super().__init__(world, **kwargs)
        self.out = bytearray()
        self.t0_ns = 0
        self._sensor.open(0)

    def _write(self, data: bytes) -> None:
        self.out += data

    def take(self) -> bytes:
        out, self.out = bytes(self.out), bytearray()
        return out


def test_the_emulator_answers_modbus_and_streams_the_worlds_readings(world):
    emu = Wire(world, serial_number="FTS-0042")
    emu.receive(rq.with_crc(bytes.fromhex("090301fe0004")))  # FC03, registers 510-513
    answer = emu.take()
    assert answer[:3] == bytes((9, 3, 8)) and rq.crc16(answer[:-2]) == int.from_bytes(answer[-2:], "little")
    assert rq.serial_number([int.from_bytes(answer[3 + 2 * i : 5 + 2 * i], "big") for i in range(4)]) == "FTS-0042"
    emu.receive(rq.with_crc(bytes.fromhex("0903012c0001")))  # register 300: none
    assert emu.take() == rq.with_crc(bytes((9, 0x83, 2)))
    emu.receive(rq.with_crc(bytes.fromhex("0910019a0001020201")))  # 0x0201 to 410: not the FT 300's value
    assert emu.take() == rq.with_crc(bytes((9, 0x90, 3))) and not emu.streaming
    emu.receive(rq.with_crc(bytes.fromhex("090300b40001"))[:-1] + b"\x00")  # a bad CRC: no answer
    emu.receive(start_request())
    assert emu.take() == rq.with_crc(bytes.fromhex("0910019a0001")) and emu.streaming

    emu.sample_due(round(0.25e9))  # world samples 0..25 due: each one frame
    parser = rq.StreamParser()
    values, _ = parser.feed(emu.take())
    reading = world.wrench(np.arange(26) * 0.01)
    assert np.array_equal(np.array(values), rq.counts_of(reading["force_S"], reading["torque_S"]))
    emu.receive(rq.with_crc(bytes.fromhex("090300b40006")))  # streaming: a Modbus request goes unanswered
    emu.corrupt_frames(2)
    emu.sample_due(round(0.30e9))
    values, _ = parser.feed(emu.take())
    assert len(values) == 3 and parser.crc_errors == 2 and [s[2] for s in emu.sent][-5:] == [1, 1, 0, 0, 0]


def test_the_emulator_stops_streaming_after_fifty_stop_bytes_only(world):
    emu = Wire(world)
    emu.receive(start_request())
    emu.receive(b"\xff" * 49 + b"\x00" + b"\xff" * 49)
    assert emu.streaming
    emu.receive(b"\xff")
    assert not emu.streaming and emu.counts.stops == 1


def test_a_scheduled_fault_parses_or_names_what_is_wrong():
    assert ScheduledFault.parse("stall@8:0.5") == ScheduledFault("stall", 8.0, 0.5)
    with pytest.raises(ValueError, match="unknown kind 'melt'"):
        ScheduledFault.parse("melt@3")


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({}, "port"),
        ({"port": "/dev/x", "slave_id": 300}, "slave_id"),
        ({"port": "/dev/x", "range_force": -1}, "range_force"),
    ],
)
def test_a_bad_option_names_its_key(options, key):
    with pytest.raises(OptionError) as info:
        RobotiqFT300Sensor(**options)
    assert info.value.key == key


def test_the_sensor_states_the_ft300s_range_rate_and_latency():
    sensor = RobotiqFT300Sensor(port="/dev/ttyUSB0")
    assert sensor.rate_hz == 100.0 and sensor.latency_s == 0.01
    assert sensor.range_force_S.tolist() == [300.0] * 3 and sensor.range_torque_S.tolist() == [30.0] * 3
