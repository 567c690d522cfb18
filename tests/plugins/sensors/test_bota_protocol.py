"""The Bota serial wire and the ``bota`` plugin's logic, without a port: frames, CRC, resynchronisation, the
status word, the device clock, temperature and the options. (Over a pty: test_bota.py.)"""

from __future__ import annotations

import time

import numpy as np
import pytest

from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.types import STATUS_DEVICE_ERROR, STATUS_OK, STATUS_SATURATED
from hapticlab.plugins.sensors import bota_protocol as bp
from hapticlab.plugins.sensors.bota import BotaSensor, stream_status
from hapticlab.plugins.sensors.bota_emulator_cli import ScheduledFault


def frames(n: int, start_us: int = 1_000_000, period_us: int = 1250, status=0, temperature=30.0) -> bytes:
    """n frames with readings i, i/10 (N, N·m) and timestamps every ``period_us`` from ``start_us``."""
    i = np.arange(n, dtype=float)
    force = np.column_stack([i, -i, 2 * i])
    return bp.encode_frames(
        np.broadcast_to(status, n), force, force / 10, start_us + period_us * np.arange(n), np.full(n, temperature)
    )


def test_the_crc_is_x25_as_bota_computes_it():
    assert bp.crc_x25(b"123456789") == 0x906E  # CRC-16/X.25's check value
    rows = np.frombuffer(b"123456789" * 3, dtype=np.uint8).reshape(3, 9)
    assert bp.crc_x25_rows(rows).tolist() == [0x906E] * 3


def test_a_frame_is_37_bytes_little_endian_with_the_crc_over_its_data():
    data = frames(1)
    assert len(data) == bp.FRAME_SIZE == 37 and data[0] == 0xAA
    assert int.from_bytes(data[-2:], "little") == bp.crc_x25(data[1:-2])
    status, *wrench, timestamp, temperature = bp.DATA.unpack(data[1:-2])
    assert (status, wrench[:3], timestamp, temperature) == (0, [0.0] * 3, 1_000_000, 30.0)


def test_the_decoder_gives_the_same_frames_whatever_the_chunks():
    data = frames(50)
    whole = bp.FrameDecoder().feed(data)
    byte_by_byte = bp.FrameDecoder()
    pieces = [byte_by_byte.feed(data[i : i + 1]) for i in range(len(data))]
    assert len(whole) == 50 and np.array_equal(np.concatenate(pieces), whole)
    np.testing.assert_array_equal(whole["wrench"][:, 0], np.arange(50, dtype=np.float32))


def test_a_bad_crc_costs_its_own_frame_and_the_decoder_resyncs_on_the_next_header():
    data = bytearray(frames(10))
    data[3 * 37 + 10] ^= 0x40  # a bit flipped in frame 3's data
    decoder = bp.FrameDecoder()
    got = decoder.feed(b"r,0,R,0" + bytes(data[:200]))  # the text answer before the stream, then frames
    got = np.concatenate([got, decoder.feed(bytes(data[200:]))])
    assert got["timestamp_us"].tolist() == [1_000_000 + 1250 * i for i in (0, 1, 2, 4, 5, 6, 7, 8, 9)]
    assert decoder.counts.crc_errors >= 1 and decoder.counts.frames == 9
    assert bytes(decoder.counts.text).startswith(b"r,0,R,0")


def test_noise_between_frames_is_skipped_and_counted():
    data = frames(4)
    noise = bytes([0xAA, 0x01, 0xAA]) + b"\x00" * 40  # headers in the noise: CRCs fail
    decoder = bp.FrameDecoder()
    got = decoder.feed(data[:74] + noise + data[74:])
    assert len(got) == 4 and decoder.counts.skipped_bytes == len(noise)


def test_the_status_word_maps_onto_the_streams_bits():
    words = np.array([0, bp.STATUS_TOOK_TOO_LONG, bp.STATUS_OVERRANGE, bp.STATUS_INVALID, bp.STATUS_RAW, 1 << 9])
    assert stream_status(words).tolist() == [
        STATUS_OK,
        STATUS_OK,  # late, but a good reading: a warning
        STATUS_SATURATED,
        STATUS_DEVICE_ERROR,
        STATUS_DEVICE_ERROR,  # not in N: the calibration is off
        STATUS_DEVICE_ERROR,  # a reserved bit: not trusted
    ]
    assert bp.describe_status(bp.STATUS_OVERRANGE | 1 << 9) == "overrange, reserved bits 0x0200"


class FakeLink:
    """What the plugin reads from, without a port: the bytes given to ``feed``."""

    def __init__(self):
        self.data = bytearray()

    def read(self) -> bytes:
        data, self.data = bytes(self.data), bytearray()
        return data

    def close(self, stop: bool = True) -> None:
        pass


def opened(**options) -> tuple[BotaSensor, FakeLink]:
    sensor = BotaSensor(port="/dev/null-bota", **options)
    sensor._link = link = FakeLink()  # as open() leaves it once the sensor runs
    return sensor, link


def test_the_plugin_times_samples_by_the_sensors_clock_across_its_32_bit_wrap():
    sensor, link = opened()  # 800 Hz
    start = 2**32 - 5 * 1250  # five frames before the µs counter wraps
    link.data += frames(10, start_us=start)
    block = sensor.read_block(2**62)
    assert np.diff(block.seq).tolist() == [1] * 9  # one grid step per frame, through the wrap
    # times from the sensor's clock (DeviceClock): never after their receipt, increasing (frames that arrive
    # together before any earlier one share the receipt's time; the spacing is checked over a pty, test_bota.py)
    assert (np.diff(block.t_ns) > 0).all() and block.t_ns[-1] <= time.monotonic_ns()
    np.testing.assert_allclose(block.force_S[:, 2], 2 * np.arange(10))
    assert block.status.tolist() == [0] * 10 and sensor.health_counters()["lost"] == 0


def test_lost_frames_statuses_and_temperature_are_counted_and_recorded():
    sensor, link = opened(temperature_interval=0.5)
    link.data += frames(3, start_us=10_000, temperature=31.0)
    link.data += frames(2, start_us=10_000 + 5 * 1250, status=bp.STATUS_OVERRANGE, temperature=33.0)
    block = sensor.read_block(2**62)
    assert block.seq.tolist()[-3:] == [block.seq[0] + 2, block.seq[0] + 5, block.seq[0] + 6]
    assert block.status.tolist() == [0, 0, 0, STATUS_SATURATED, STATUS_SATURATED]
    counters = sensor.health_counters()
    assert (counters["lost"], counters["status_frames"], counters["frames"]) == (2, 2, 5)
    events = sensor.drain_events()
    saturated = [e for e in events if e.kind == "sensor_saturated"]
    assert len(saturated) == 1 and saturated[0].data["status_word"] == bp.STATUS_OVERRANGE
    temperature = [e for e in events if e.kind == "sensor_temperature"]
    assert temperature[0].data["temperature_C"] == pytest.approx((3 * 31 + 2 * 33) / 5)
    assert temperature[0].data["seq"] == block.seq[-1] and sensor.temperature_C == 33.0


def test_a_sensor_that_restarts_its_clock_is_an_event_and_the_stream_goes_on():
    sensor, link = opened()
    link.data += frames(3, start_us=50_000_000)
    first = sensor.read_block(2**62)
    link.data += frames(3, start_us=1_000)  # a reboot: the clock starts again
    second = sensor.read_block(2**62)
    assert len(first) == len(second) == 3 and sensor.health_counters()["restarts"] == 1
    assert second.t_ns[0] > first.t_ns[-1]
    assert [e.kind for e in sensor.drain_events()].count("sensor_restart") == 1


def test_the_rate_asked_for_becomes_a_sinc_length_and_the_rate_in_use():
    assert (BotaSensor(port="p").sinc_length, BotaSensor(port="p").rate_hz) == (64, 800.0)
    assert BotaSensor(port="p", rate_hz=100).sinc_length == 512
    sensor = BotaSensor(port="p", rate_hz=1000)
    assert sensor.sinc_length == 51 and sensor.rate_hz == pytest.approx(1003.92, abs=0.01)
    assert bp.filter_command(64) == b"f,64,0,0,1" and bp.communication_command(False) == b"c,0,1,0,4"


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({}, "sensor.port"),
        ({"port": "p", "rate_hz": 2000}, "sensor.rate_hz"),
        ({"port": "p", "range_force": -1}, "sensor.range_force"),
        ({"port": "p", "receive_timeout": 0}, "sensor.receive_timeout"),
    ],
)
def test_a_bad_config_is_one_line_naming_the_key(options, key):
    with pytest.raises(ConfigError, match=f"^{key}: "):
        Registry().create("sensor", "bota", options, where="sensor")


def test_an_emulator_fault_parses_from_the_command_line():
    assert ScheduledFault.parse("crc@5:3") == ScheduledFault("crc", 5.0, 3.0)
    assert ScheduledFault.parse("unplug@12") == ScheduledFault("unplug", 12.0)
    with pytest.raises(ValueError, match="unknown kind 'melt'"):
        ScheduledFault.parse("melt@1")
