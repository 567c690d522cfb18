"""The ``robotiq_ft300`` sensor: a Robotiq FT 300 on a serial port (its USB-RS485 adapter), in stream mode.

``open`` stops any stream left running (50 0xFF bytes), reads the sensor's firmware version, serial
number and production year over Modbus RTU with ``minimalmodbus`` (``robotiq_link.py``), and
starts the 100 Hz stream (0x0200 to register 410). Each loop tick ``read_block`` takes the bytes
received, parses the frames (``robotiq_protocol.StreamParser``: synchronised on the 0x20 0x4E
header, CRC-16/Modbus checked) and hands over the good ones in N and N·m.

Single faults, each safe on its own:

* a frame with a bad CRC is counted and dropped, never delivered; garbage between frames is
  skipped until a header whose frame checks;
* a stalled stream delivers nothing: the loop's samples go stale and the gate holds the haptic force
  at zero; after ``receive_timeout`` a ``sensor_timeout`` event, the start request sent again every
  ``receive_timeout`` while silent, ``sensor_resumed`` when frames return;
* a disconnect (the port's read fails) is one ``sensor_disconnected`` event naming the port and the
  error; the port is tried again every ``reconnect_interval`` while its path exists.

Times: the stream carries no counter, so each frame's place in the stream (its slot: good frames and
damaged ones) is the device counter of a :class:`~hapticlab.plugins.device_clock.DeviceClock` at
100 Hz, which stamps frames by the sensor's own spacing on the lower envelope of their receipt
times. A batch whose newest frame comes more than ``GAP_PERIODS`` periods late follows a stall
(``stalls``): the clock's offset jumps by the whole periods it is late, so the stamps follow time
(a lower envelope alone would rise only at ``clock_slew_ppm`` and leave them in the past). ``seq`` does
not jump: the stream has no counter to say whether the sensor paused or frames were lost, and a
process starved for the while (an emulator on a loaded machine) makes frames late without losing any.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import OptionError, integer, number, rated_range
from hapticlab.core.types import NO_WRENCHES, STATUS_SATURATED, Event, WrenchBlock, WrenchSample
from hapticlab.plugins.device_clock import DeviceClock
from hapticlab.plugins.sensors import robotiq_protocol as rq
from hapticlab.plugins.sensors.robotiq_link import FT300Link, FT300LinkError, start_request
from hapticlab.plugins.sensors.stream_events import health_event

LATENCY_S = 0.01
"""How much older than now the newest frame can be in ordinary operation (HasLatency), s: a frame takes
8.3 ms on the wire at 19200 bit/s, plus the USB adapter's latency (set an FTDI adapter's
``latency_timer`` to 1 ms; its default 16 ms makes frames arrive in pairs, late)."""
GAP_PERIODS = 5
"""A batch's newest frame this many periods later than the clock expects: a stall, the clock jumps."""
HEALTH_COUNTERS = ("frames", "crc_errors", "garbage_bytes", "stalls", "timeouts", "restarts", "disconnects")
"""The stream's health counters (:meth:`RobotiqFT300Sensor.health_counters`), counts since ``open``."""
FAULT_COUNTERS = frozenset(HEALTH_COUNTERS) - {"frames"}


class RobotiqFT300Sensor:
    """A Robotiq FT 300 force/torque sensor in stream mode (SensorSource, ReadsBlocks, EmitsEvents,
    HasCalibration, HasRange, HasLatency, ReportsHealth).

    Parameters
    ----------
    port : the serial device of the sensor's USB-RS485 adapter (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``)
        or the emulator's ``/dev/pts/N``. Required.
    slave_id : the sensor's Modbus slave id (9 from the factory).
    rate_hz : the stream's rate, Hz: 100, the only one the FT 300 streams at (accepted so that a preset's
        ``rate_hz`` can be set to it rather than removed).
    baudrate : its serial rate, bit/s (19200 from the factory).
    receive_timeout : no frame for this long is a timeout: an event, and the start request is sent again
        every ``receive_timeout`` while silent, s. The haptic force is zero long before (stale samples).
    open_timeout : how long ``open`` waits for the stream to stop, each Modbus answer and the first frame, s.
    range_force, range_torque : the rated range per axis (a number or 3), N and N·m: a reading beyond it is
        refused as implausible (HasRange). Default the FT 300's ±300 N and ±30 N·m.
    reconnect_interval : how often a disconnected port is tried again, s.
    health_interval : the health counters are recorded as an event at most this often, s.
    clock_slew_ppm : how fast the clock's offset may rise (:class:`DeviceClock`), ppm.
    """

    def __init__(
        self,
        port: str = "",
        slave_id: int = rq.SLAVE_ID,
        rate_hz: float = rq.STREAM_RATE_HZ,
        baudrate: int = rq.BAUDRATE,
        receive_timeout: float = 0.1,
        open_timeout: float = 1.0,
        range_force: float | list[float] = rq.RANGE_FORCE_N,
        range_torque: float | list[float] = rq.RANGE_TORQUE_NM,
        reconnect_interval: float = 1.0,
        health_interval: float = 1.0,
        clock_slew_ppm: float = 200.0,
    ):
        if not isinstance(port, str) or not port.strip():
            raise OptionError(
                "port",
                "must name the sensor's serial port, e.g. --set sensor.port=/dev/ttyUSB0 "
                f"(hapticlab emulate robotiq-ft300 prints one), got {port!r}",
            )
        self.port = port.strip()
        self.slave_id = integer("slave_id", slave_id, minimum=1, maximum=247, hint=" (a Modbus slave id)")
        self.baudrate = integer("baudrate", baudrate, minimum=1, hint=" bit/s")
        self.receive_timeout, self.open_timeout, self.reconnect_interval, health_interval = (
            number(key, value, above=0, hint=" s")
            for key, value in (
                ("receive_timeout", receive_timeout),
                ("open_timeout", open_timeout),
                ("reconnect_interval", reconnect_interval),
                ("health_interval", health_interval),
            )
        )
        self.range_force_S = rated_range("range_force", range_force)
        """(3,) rated range per force axis, N (HasRange)."""
        self.range_torque_S = rated_range("range_torque", range_torque)
        """(3,) rated range per torque axis, N·m."""
        self.rate_hz = number(
            "rate_hz",
            rate_hz,
            minimum=rq.STREAM_RATE_HZ,
            maximum=rq.STREAM_RATE_HZ,
            hint=" Hz (the FT 300 streams at 100)",
        )
        self.latency_s = LATENCY_S
        self.calibration: dict[str, str] = {
            "sensor": "Robotiq FT 300",
            "port": self.port,
            "force_per_count": "0.01 N",
            "torque_per_count": "0.001 N·m",
        }
        """What the sensor reports of itself (HasCalibration): serial number, firmware, production year (after open)."""
        self.clock = DeviceClock(rq.STREAM_RATE_HZ, number("clock_slew_ppm", clock_slew_ppm, minimum=0, hint=" ppm"))
        self.health_interval_ns = int(health_interval * 1e9)
        self.parser = rq.StreamParser()
        self._link: FT300Link | None = None
        self._slot_base = 0  # the counter of the parser's slot 0 (a new stream goes on from the last)
        self._last_k: int | None = None
        self._last_t_ns = -1
        self._pending = NO_WRENCHES
        self._events: list[Event] = []
        self._counters = dict.fromkeys(HEALTH_COUNTERS, 0)
        self._recorded = dict(self._counters)
        self._next_health_ns = 0
        self._last_frame_ns = self._silent_since_ns = 0
        self._timed_out = False
        self._next_try_ns = 0
        self._reconnecting: threading.Thread | None = None
        self._opened: tuple[FT300Link, bytes, int] | None = None  # what the reconnecting thread opened

    # ------------------------------------------------------------------ life cycle

    def open(self, t0_ns: int) -> None:
        """Connect and start the stream; raises ConnectionError in one line naming the port and what failed."""
        self._connect(t0_ns)
        self._next_health_ns = t0_ns + self.health_interval_ns

    def _connect(self, t_ns: int) -> None:
        link = FT300Link(self.port, self.slave_id, self.baudrate, self.open_timeout)
        first = link.open()
        self._start(link, first, time.monotonic_ns(), t_ns)

    def _start(self, link: FT300Link, first: bytes, received_ns: int, t_ns: int) -> None:
        """A link that streams: its event, a new stream for the parser and the clock, its first bytes."""
        self._link = link
        self.calibration.update(link.info)
        self._events.append(
            Event(
                t_ns,
                "sensor_connected",
                f"Robotiq FT 300 {link.info['serial_number']} (firmware {link.info['firmware']}, "
                f"{link.info['production_year']}) on {self.port}: streaming at 100 Hz"
                + (" (it was streaming already: stopped and restarted)" if link.streamed_before else ""),
                dict(link.info),
            )
        )
        self.parser.reset()
        self.clock.reset()  # a new stream: its first frame anchors the clock again
        if self._last_k is not None:
            self._slot_base = self._last_k + 1 - self.parser.slots
        self._last_frame_ns = self._silent_since_ns = received_ns
        self._take(first, received_ns)

    def close(self) -> None:
        """Stop the stream (the stop bytes) and close the port; the final counters become an event."""
        if self._reconnecting is not None:
            self._reconnecting.join(self.open_timeout + 1.0)
        for link in (self._link, None if self._opened is None else self._opened[0]):
            if link is not None:
                link.close()
        self._link = self._opened = None
        self._health_event(time.monotonic_ns(), final=True)

    # ------------------------------------------------------------------ the stream

    def read(self, until_ns: int) -> list[WrenchSample]:
        """Every frame received and not yet returned whose time is <= ``until_ns``, in time order."""
        return self.read_block(until_ns).samples()

    def read_block(self, until_ns: int) -> WrenchBlock:
        """:meth:`read` as arrays (ReadsBlocks)."""
        if self._link is None:
            self._reconnect(until_ns)
        else:
            try:
                data = self._link.read()
            except FT300LinkError as exc:
                self._lost(until_ns, exc)
            else:
                if data:
                    self._take(data, time.monotonic_ns())
                self._watch(until_ns)
        if until_ns >= self._next_health_ns:
            self._next_health_ns = until_ns + self.health_interval_ns
            self._health_event(until_ns)
        due, self._pending = self._pending.split(until_ns)
        return due

    def _take(self, data: bytes, received_ns: int) -> None:
        """Parse ``data``; the good frames, in SI units and stamped, onto the pending readings."""
        crc_before = self.parser.crc_errors
        values, slots = self.parser.feed(data)
        self._counters.update(
            frames=self.parser.frames, crc_errors=self.parser.crc_errors, garbage_bytes=self.parser.garbage_bytes
        )
        if self.parser.crc_errors != crc_before:
            self._last_frame_ns = received_ns  # a damaged frame is still the sensor talking
        if not values:
            return
        k = np.asarray(slots, dtype=np.int64) + self._slot_base
        if self.clock.offset_ns is not None:
            late = (received_ns - (k[-1] * self.clock.period_ns + self.clock.offset_ns)) / self.clock.period_ns
            if late > GAP_PERIODS:  # after a stall: the clock jumps to time, by whole periods
                self.clock.offset_ns += int(late) * self.clock.period_ns  # never past this frame's receipt
                self._counters["stalls"] += 1
        if (
            self.clock.offset_ns is None
        ):  # a new stream: anchored on the batch's newest frame, so the earlier are earlier
            self.clock.offset_ns, self.clock.last_k = received_ns - float(k[-1]) * self.clock.period_ns, int(k[0])
        t_ns = self.clock.stamp_many(k, received_ns)
        t_ns = np.maximum(t_ns, self._last_t_ns + 1 + np.arange(len(t_ns)))  # never back, across a new stream too
        self._last_t_ns, self._last_k = int(t_ns[-1]), int(k[-1])
        counts = np.array(values, dtype=np.int64)
        wrench = counts * rq.SI_PER_COUNT
        status = np.where(np.abs(counts).max(axis=1) >= rq.INT16, STATUS_SATURATED, 0).astype(np.int64)
        block = WrenchBlock(t_ns, np.ascontiguousarray(wrench[:, :3]), np.ascontiguousarray(wrench[:, 3:]), k, status)
        self._pending = WrenchBlock.concatenate([self._pending, block]) if len(self._pending) else block
        self._last_frame_ns = self._silent_since_ns = received_ns

    def _watch(self, now_ns: int) -> None:
        """Receive timeout: events when the stream falls silent and returns; the start request again."""
        mono_ns = time.monotonic_ns()
        silent_ns = mono_ns - self._last_frame_ns
        timeout_ns = self.receive_timeout * 1e9
        if not self._timed_out and silent_ns > timeout_ns:
            self._timed_out = True
            self._counters["timeouts"] += 1
            self._events.append(
                Event(
                    now_ns,
                    "sensor_timeout",
                    f"no Robotiq FT 300 frame on {self.port} for {silent_ns * 1e-6:.0f} ms: no sensor data, haptic "
                    "force held at zero; asking the sensor to stream again",
                    {"silent_s": silent_ns * 1e-9},
                )
            )
        elif self._timed_out and silent_ns <= timeout_ns:
            self._timed_out = False
            self._events.append(Event(now_ns, "sensor_resumed", f"Robotiq FT 300 on {self.port} streams again"))
        if self._timed_out and mono_ns - self._silent_since_ns > timeout_ns:
            self._silent_since_ns = mono_ns
            self._counters["restarts"] += 1
            try:
                self._link.write(start_request(self.slave_id))  # type: ignore[union-attr]  # read_block checked it
            except FT300LinkError as exc:
                self._lost(now_ns, exc)

    def _lost(self, now_ns: int, exc: FT300LinkError) -> None:
        """The port failed: one event, the port closed, tried again every ``reconnect_interval``."""
        if self._link is not None:
            self._link.close(stop=False)
            self._link = None
        self._counters["disconnects"] += 1
        self._next_try_ns = time.monotonic_ns() + int(self.reconnect_interval * 1e9)
        self._events.append(
            Event(
                now_ns,
                "sensor_disconnected",
                f"{exc}: no sensor data, haptic force held at zero; trying the port every "
                f"{self.reconnect_interval:g} s",
                {"port": self.port},
            )
        )

    def _reconnect(self, now_ns: int) -> None:
        """Pick up a link the reconnecting thread opened; start that thread every ``reconnect_interval`` while
        the port's path exists. Opening takes ~0.1-1 s (the stop bytes' quiet, the registers): never in the loop."""
        opened, self._opened = self._opened, None
        if opened is not None:
            self._reconnecting = None
            self._start(*opened, now_ns)
            self._timed_out = False
            self._events.append(Event(now_ns, "sensor_reconnected", f"Robotiq FT 300 on {self.port} is back"))
            return
        mono_ns = time.monotonic_ns()
        busy = self._reconnecting is not None and self._reconnecting.is_alive()
        if busy or mono_ns < self._next_try_ns:
            return
        self._next_try_ns = mono_ns + int(self.reconnect_interval * 1e9)
        if os.path.exists(self.port):  # gone (unplugged): nothing to try
            self._reconnecting = threading.Thread(target=self._open_link, name=f"ft300 {self.port}", daemon=True)
            self._reconnecting.start()

    def _open_link(self) -> None:
        link = FT300Link(self.port, self.slave_id, self.baudrate, self.open_timeout)
        try:
            first = link.open()
        except FT300LinkError:
            return
        self._opened = (link, first, time.monotonic_ns())

    # ------------------------------------------------------------------ capabilities

    def _health_event(self, t_ns: int, final: bool = False) -> None:
        """The counters as an event when a fault counter moved (or at the end of the stream)."""
        who = f"Robotiq FT 300 on {self.port}"
        event = health_event(t_ns, who, self._counters, self._recorded, FAULT_COUNTERS, final)
        if event is not None:
            self._recorded = dict(self._counters)
            self._events.append(event)

    def health_counters(self) -> dict[str, int]:
        """Since ``open``: ``frames`` parsed, ``crc_errors`` (frames dropped), ``garbage_bytes`` skipped,
        ``stalls`` (a frame more than ``GAP_PERIODS`` periods late: the clock jumped), ``timeouts``,
        ``restarts`` (start requests sent again), ``disconnects``."""
        return dict(self._counters)

    def drain_events(self) -> list[Event]:
        """Connection, timeouts, disconnects and health since the last call (EmitsEvents)."""
        events, self._events = self._events, []
        return events


@hookimpl
def register_sensors(register):
    """Register the Robotiq FT 300 as ``robotiq_ft300``."""
    register("robotiq_ft300", RobotiqFT300Sensor)
