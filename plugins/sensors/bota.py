"""The ``bota`` sensor: a Bota Systems serial F/T sensor (BFT-*-SER: SensONE, Rokubi, MiniONE serial).

The wire is ``bota_protocol.py``. ``open`` takes the port (raw, 460 800 baud, exclusive),
puts the sensor in configuration mode (``C``), sets binary frames with the calibration on
(``c``), the sinc length of ``rate_hz`` (``f``), and runs it (``R``); each answer is waited for.
Each ``read`` then drains the port without blocking and decodes every whole frame:

* **SI units** already: float32 N and N·m in the sensor frame.
* **Time**: the frame's µs timestamp (the sensor's clock, unwrapped past 2³²) mapped onto the
  session's monotonic clock by :class:`~hapticlab.plugins.device_clock.DeviceClock`; a sample's
  ``seq`` is its index on the sensor's sample grid (timestamp / period), so a gap in ``seq`` is a
  frame lost on the way.
* **Status**: the status word becomes the stream's bits (overrange → ``STATUS_SATURATED``; invalid
  or raw measurements, or a reserved bit → ``STATUS_DEVICE_ERROR``; "took too long" is a warning
  only), with an event whenever it changes.
* **Temperature** (°C): a ``sensor_temperature`` event every ``temperature_interval`` (mean, min,
  max of the frames since the last, with the last sample's ``seq``), and ``temperature_C``.
* **Faults**: a bad CRC is counted and dropped, the decoder resynchronises on the next header; no
  frame for ``receive_timeout`` is a ``sensor_timeout`` event (the loop has zeroed the force
  already: the samples are stale); a port that fails (unplugged) raises one line.
"""

from __future__ import annotations

import time

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import OptionError, boolean, number, rated_range
from hapticlab.core.types import (
    NO_WRENCHES,
    STATUS_DEVICE_ERROR,
    STATUS_OK,
    STATUS_SATURATED,
    Event,
    WrenchBlock,
    WrenchSample,
)
from hapticlab.plugins.device_clock import DeviceClock
from hapticlab.plugins.sensors import bota_protocol as bp
from hapticlab.plugins.sensors.bota_link import BotaLink
from hapticlab.plugins.sensors.stream_events import health_event, status_event

SERIAL_LATENCY_S = 0.003
"""How much older than now the newest frame can be in ordinary operation (HasLatency), s: the USB adapter's
latency timer set to 1 ms, and the loop draining the port once a tick."""
HEALTH_COUNTERS = ("frames", "crc_errors", "skipped_bytes", "lost", "status_frames", "restarts", "timeouts")
"""The stream's health counters (:meth:`BotaSensor.health_counters`), counts since ``open``."""


def stream_status(words: np.ndarray) -> np.ndarray:
    """The stream's status bits (``core.types``) of Bota status words: (n,) int64."""
    words = np.asarray(words, dtype=np.int64)
    bits = np.where(words & bp.STATUS_OVERRANGE, STATUS_SATURATED, STATUS_OK)
    error = words & ~(bp.STATUS_OVERRANGE | bp.STATUS_TOOK_TOO_LONG) != 0
    return bits | np.where(error, STATUS_DEVICE_ERROR, STATUS_OK)


class BotaSensor:
    """A Bota Systems serial sensor (SensorSource, ReadsBlocks, EmitsEvents, HasCalibration, HasRange,
    ReportsHealth, HasLatency).

    Parameters
    ----------
    port : the serial device (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, the emulator's ``/dev/pts/N``).
    rate_hz : the sample rate asked for, Hz; the sensor runs at 51 200 / sinc_length Hz with
        ``sinc_length = round(51 200 / rate_hz)`` in 51..512 (1004–100 Hz): :attr:`rate_hz` is that rate.
        Default 800 (sinc 64).
    temperature_compensation : the sensor's own temperature compensation (Bota recommends it off).
    range_force, range_torque : the sensor's rated range per axis (a number or 3), N and N·m (the data
        sheet's); a reading beyond it with a good status is refused as implausible. Default: unchecked.
    open_timeout : how long each step of the set-up may take, s (a sensor reboots when its port opens).
    receive_timeout : no frame for this long is a ``sensor_timeout`` event, s.
    temperature_interval : the temperature is recorded this often, s.
    health_interval : the health counters are recorded at most this often when they moved, s.
    latency : how old the newest frame may be in ordinary operation (HasLatency), s.
    clock_slew_ppm : how fast the device-clock offset may rise (:class:`DeviceClock`), ppm.
    """

    def __init__(
        self,
        port: str = "",
        rate_hz: float = 800.0,
        temperature_compensation: bool = False,
        range_force: float | list[float] | None = None,
        range_torque: float | list[float] | None = None,
        open_timeout: float = 5.0,
        receive_timeout: float = 0.1,
        temperature_interval: float = 1.0,
        health_interval: float = 1.0,
        latency: float = SERIAL_LATENCY_S,
        clock_slew_ppm: float = 200.0,
    ):
        if not isinstance(port, str) or not port.strip():
            raise OptionError("port", "must name the sensor's serial port (/dev/ttyUSB0, or the emulator's /dev/pts/N)")
        self.port = port.strip()
        lo, hi = (bp.rate_of(n) for n in reversed(bp.SINC_LENGTHS))
        asked = number("rate_hz", rate_hz, minimum=lo * 0.999, maximum=hi * 1.001, hint=" Hz (51200/sinc, 51..512)")
        self.sinc_length = min(max(round(bp.SINC_CLOCK_HZ / asked), bp.SINC_LENGTHS[0]), bp.SINC_LENGTHS[1])
        self.rate_hz = bp.rate_of(self.sinc_length)
        self.temperature_compensation = boolean("temperature_compensation", temperature_compensation)
        self.open_timeout, self.receive_timeout, temperature_interval, health_interval = (
            number(key, value, above=0, hint=" s")
            for key, value in (
                ("open_timeout", open_timeout),
                ("receive_timeout", receive_timeout),
                ("temperature_interval", temperature_interval),
                ("health_interval", health_interval),
            )
        )
        self.latency_s = number("latency", latency, minimum=0, hint=" s")
        self.range_force_S = rated_range("range_force", range_force)
        """(3,) rated range per force axis, N (HasRange; inf: unchecked)."""
        self.range_torque_S = rated_range("range_torque", range_torque)
        """(3,) rated range per torque axis, N·m."""
        self.calibration: dict[str, str] = {
            "sensor": "Bota Systems serial (BFT-*-SER)",
            "port": self.port,
            "sinc_length": str(self.sinc_length),
            "rate_hz": f"{self.rate_hz:g}",
            "temperature_compensation": str(self.temperature_compensation).lower(),
            "units": "N, N·m (the sensor's calibration matrix, on)",
        }
        """The settings in use (HasCalibration)."""
        self.clock = DeviceClock(1e6, number("clock_slew_ppm", clock_slew_ppm, minimum=0, hint=" ppm"))
        self.temperature_C = float("nan")
        """The last frame's temperature, °C (NaN before the first)."""
        self._period_us = 1e6 / self.rate_hz
        self._temperature_ns, self._health_ns = int(temperature_interval * 1e9), int(health_interval * 1e9)
        self._link: BotaLink | None = None
        self._decoder = bp.FrameDecoder()
        self._pending = NO_WRENCHES
        self._events: list[Event] = []
        self._counters = dict.fromkeys(HEALTH_COUNTERS, 0)
        self._recorded = dict(self._counters)
        self._word = 0
        self._last_us: int | None = None  # the last raw timestamp, and the unwrapped one
        self._unwrapped_us = 0
        self._last_seq: int | None = None
        self._last_frame_ns = 0
        self._timed_out = False
        self._temps: list[np.ndarray] = []
        self._next_temperature_ns = self._next_health_ns = 0

    # ------------------------------------------------------------------ life cycle

    def open(self, t0_ns: int) -> None:
        """Take the port, configure the sensor, run it, and wait for its first frame.

        Raises ConnectionError naming the port and the step that failed.
        """
        link = BotaLink(self.port, self.open_timeout)
        try:
            rest = link.set_up(self.temperature_compensation, self.sinc_length)
            self._link = link
            self._decoder.reset()
            self._ingest(rest, time.monotonic_ns())
            deadline = time.monotonic() + self.open_timeout
            while not len(self._pending) and time.monotonic() < deadline:
                link.wait(0.01)
                self._poll()
            if not len(self._pending):
                counts = self._decoder.counts
                raise ConnectionError(
                    f"Bota sensor {self.port}: running, but no valid frame within {self.open_timeout:g} s "
                    f"({counts.crc_errors} CRC errors, {counts.skipped_bytes} other bytes)"
                )
        except BaseException:
            self._link = None
            link.close(stop=False)
            raise
        self._events.append(
            Event(
                t0_ns,
                "sensor_calibration",
                f"Bota sensor {self.port}: {self.rate_hz:g} Hz (sinc {self.sinc_length}), temperature compensation "
                f"{'on' if self.temperature_compensation else 'off'}",
                dict(self.calibration),
            )
        )
        self._next_temperature_ns = self._next_health_ns = t0_ns

    def close(self) -> None:
        """Stop the stream (``C``: configuration mode) and let the port go; the final counters become an event."""
        if self._link is None:
            return
        self._link.close()
        self._link = None
        self._health_event(time.monotonic_ns(), final=True)

    # ------------------------------------------------------------------ the stream

    def read(self, until_ns: int) -> list[WrenchSample]:
        """Every sample received and not yet returned whose time is <= ``until_ns``, in time order."""
        return self.read_block(until_ns).samples()

    def read_block(self, until_ns: int) -> WrenchBlock:
        """:meth:`read` as arrays (ReadsBlocks)."""
        if self._link is None:
            raise RuntimeError("read() before open()")
        self._poll()
        self._watch(until_ns)
        due, self._pending = self._pending.split(until_ns)
        return due

    def _poll(self) -> None:
        data = self._link.read()  # type: ignore[union-attr]  # open() made it
        if data:
            self._ingest(data, time.monotonic_ns())

    def _ingest(self, data: bytes, received_ns: int) -> None:
        """Decode ``data`` (all there by ``received_ns``) onto the pending samples."""
        frames = self._decoder.feed(data)
        counts = self._decoder.counts
        self._counters.update(frames=counts.frames, crc_errors=counts.crc_errors, skipped_bytes=counts.skipped_bytes)
        if not len(frames):
            return
        raw = frames["timestamp_us"].astype(np.int64)
        previous = self._last_us if self._last_us is not None else int(raw[0])
        steps = np.diff(raw, prepend=previous) % 2**32  # unwrapped past 2**32 µs (71.6 min)
        back = np.flatnonzero(steps > 2**31)  # the sensor's clock went back: it restarted
        unwrapped = self._unwrapped_us + np.cumsum(steps)
        if self._last_us is None:
            unwrapped = unwrapped + int(raw[0])
        if len(back):
            self._counters["restarts"] += len(back)
            self._events.append(Event(received_ns, "sensor_restart", f"Bota sensor {self.port} restarted its clock"))
            self.clock.reset()
            self._last_seq = None
            keep = np.arange(len(frames)) >= back[-1]  # the frames from the restart on
            frames, raw = frames[keep], raw[keep]
            unwrapped = raw.copy()
        self._last_us, self._unwrapped_us = int(raw[-1]), int(unwrapped[-1])
        seq = np.rint(unwrapped / self._period_us).astype(np.int64)
        steps = np.diff(seq, prepend=seq[0] if self._last_seq is None else self._last_seq)
        self._counters["lost"] += int(np.clip(steps - 1, 0, None).sum())
        self._last_seq = int(seq[-1])
        t_ns = self.clock.stamp_many(unwrapped, received_ns)
        words = frames["status"].astype(np.int64)
        bits = stream_status(words)
        if words.any() or self._word:
            self._counters["status_frames"] += int(np.count_nonzero(words))
            for i in np.flatnonzero(words != np.concatenate([[self._word], words[:-1]])).tolist():
                self._status_event(int(t_ns[i]), int(words[i]))
        wrench = frames["wrench"].astype(np.float64)
        block = WrenchBlock(
            np.asarray(t_ns, dtype=np.int64),
            np.ascontiguousarray(wrench[:, :3]),
            np.ascontiguousarray(wrench[:, 3:]),
            seq,
            bits.astype(np.int64),
        )
        self._pending = WrenchBlock.concatenate([self._pending, block]) if len(self._pending) else block
        temperature = frames["temperature_C"].astype(np.float64)
        self._temps.append(np.column_stack([temperature, seq]))
        self.temperature_C = float(temperature[-1])
        self._last_frame_ns = received_ns

    def _status_event(self, t_ns: int, word: int) -> None:
        previous, self._word = self._word, word
        bits = int(stream_status(np.array([word]))[0])
        description = f"0x{word:04x}: {bp.describe_status(word)}"
        self._events.append(status_event(t_ns, f"Bota sensor {self.port}", word, previous, bits, description))

    def _watch(self, now_ns: int) -> None:
        """Receive timeout, temperature and health: events."""
        silent_ns = time.monotonic_ns() - self._last_frame_ns
        if not self._timed_out and silent_ns > self.receive_timeout * 1e9:
            self._timed_out = True
            self._counters["timeouts"] += 1
            self._events.append(
                Event(
                    now_ns,
                    "sensor_timeout",
                    f"no frame from the Bota sensor {self.port} for {silent_ns * 1e-6:.0f} ms: no sensor data, "
                    "haptic force held at zero",
                    {"silent_s": silent_ns * 1e-9},
                )
            )
        elif self._timed_out and silent_ns <= self.receive_timeout * 1e9:
            self._timed_out = False
            self._events.append(Event(now_ns, "sensor_resumed", f"Bota sensor {self.port} streams again"))
        if now_ns >= self._next_temperature_ns and self._temps:
            self._next_temperature_ns = now_ns + self._temperature_ns
            temps = np.concatenate(self._temps)
            self._temps = []
            mean = float(np.mean(temps[:, 0]))
            self._events.append(
                Event(
                    now_ns,
                    "sensor_temperature",
                    f"Bota sensor {self.port}: {mean:.2f} °C",
                    {
                        "temperature_C": mean,
                        "min_C": float(temps[:, 0].min()),
                        "max_C": float(temps[:, 0].max()),
                        "frames": len(temps),
                        "seq": int(temps[-1, 1]),
                    },
                )
            )
        if now_ns >= self._next_health_ns:
            self._next_health_ns = now_ns + self._health_ns
            self._health_event(now_ns)

    def _health_event(self, t_ns: int, final: bool = False) -> None:
        faults = self._counters.keys() - {"frames"}
        event = health_event(t_ns, f"Bota sensor {self.port}", self._counters, self._recorded, faults, final)
        if event is not None:
            self._recorded = dict(self._counters)
            self._events.append(event)

    # ------------------------------------------------------------------ capabilities

    def health_counters(self) -> dict[str, int]:
        """The stream's health counters since ``open`` (:data:`HEALTH_COUNTERS`): frames kept, CRC errors, bytes
        skipped while resynchronising, frames lost (gaps in ``seq``), frames with a status bit, clock restarts,
        receive timeouts."""
        return dict(self._counters)

    def drain_events(self) -> list[Event]:
        """Settings, status changes, timeouts, temperature and health since the last call (EmitsEvents)."""
        events, self._events = self._events, []
        return events


@hookimpl
def register_sensors(register):
    """Register the Bota Systems serial sensor as ``bota``."""
    register("bota", BotaSensor)
