"""The ``netft`` sensor: an ATI Net F/T (or anything speaking its RDT protocol) over UDP.

Two receivers of the RDT stream (``receiver``; ``netft_receivers.py``):

* ``"hapticlab"`` (default): :mod:`.rdt`, our own: a connected UDP socket drained
  once per loop tick, every record of the tick parsed with one ``np.frombuffer``,
  health counted on the batch, and a status word (saturation) never stops
  the stream. Written because pynetft falls short for the stream.
* ``"pynetft"``: the community client, kept for comparison. It receives on its
  own thread into a bounded queue that ``read`` drains, costs more Python per
  sample, and restarts its stream (a gap without records) after any record
  whose status word reports an error. What each costs: docs/devices.md.

Both fetch the calibration from the sensor's ``netftapi2.xml`` (or take it
from the config), and both feed what this module adds:

* **SI units**: counts or the sensor's units (often N and N·mm) become N and N·m.
* **The device clock**: each record carries ``ft_sequence``, the Net F/T's
  internal sample counter (7000/s, decimated with the RDT rate); it is
  unwrapped past 2³² (and is the sample's ``seq``) and mapped onto the session's
  monotonic clock by :class:`~hapticlab.plugins.device_clock.DeviceClock`, so
  sample times are the device's, without the network's jitter.
* **Status**: the 32-bit ATI status word becomes the stream's
  ``STATUS_SATURATED`` / ``STATUS_DEVICE_ERROR`` bits, and an event names
  its bits whenever it changes.
* **Health** (:meth:`NetFTSensor.health_counters`) and **events**: the
  counters when they change (at most once per ``health_interval``), a
  receive timeout (the loop then has no sensor data: the haptic force is
  held at zero) and the stream's return.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import OptionError, choice, integer, number, rated_range
from hapticlab.core.types import NO_WRENCHES, Event, WrenchBlock, WrenchSample
from hapticlab.plugins.device_clock import DeviceClock
from hapticlab.plugins.sensors.netft_protocol import (
    FORCE_UNITS,
    FT_RATE_HZ,
    RDT_PORT,
    TORQUE_UNITS,
    Calibration,
    describe_status,
    stream_status,
    stream_status_array,
)
from hapticlab.plugins.sensors.netft_receivers import HapticlabLink, PynetftLink
from hapticlab.plugins.sensors.rdt import COUNTER_DOC, RdtBatch
from hapticlab.plugins.sensors.stream_events import health_event, status_event

HEALTH_COUNTERS = tuple(COUNTER_DOC)
"""The stream's health counters (:meth:`NetFTSensor.health_counters`), counts since ``open``."""
RECEIVERS = ("hapticlab", "pynetft")
NETWORK_LATENCY_S = 0.003
"""How much older than now the newest record can be in ordinary operation (HasLatency), s: the
network, and the loop draining the socket once a tick (a record just missed waits a loop period)."""


class NetFTSensor:
    """An ATI Net F/T sensor over RDT/UDP (SensorSource, ReadsBlocks, EmitsEvents, HasCalibration, HasRange,
    ReportsHealth).

    Parameters
    ----------
    address : the sensor's IP address or host name.
    rdt_port : its RDT UDP port.
    http_port : its HTTP port (``netftapi2.xml``: the calibration).
    rate_hz : the RDT output rate set on the sensor (``comrdtrate``), Hz: the loop's stale timeout.
    ft_rate_hz : the rate ``ft_sequence`` counts at (7000 on every Net F/T), Hz.
    receiver : ``"hapticlab"`` (:mod:`.rdt`, default) or ``"pynetft"`` (the community client).
    receive_timeout : no record for this long is a timeout: an event, and the start request is sent
        again (hapticlab, every ``receive_timeout`` while silent) or pynetft reconnects, s.
    counts_per_force, counts_per_torque, force_unit, torque_unit : a calibration overriding the
        sensor's (all four or none): counts per force unit, per torque unit, and the units
        (``N``, ``lbf``, ... and ``N-m``, ``N-mm``, ``lbf-in``, ...).
    recovery : ``"reconnect"`` (keep trying after a timeout or a fault) or ``"fail_stop"`` (the first
        timeout, or with pynetft any fault, ends the stream: ``read`` raises and the session ends).
    range_force, range_torque : the sensor's rated range per axis (a number or 3), N and N·m; a
        reading beyond it with a good status is refused as implausible. Default: unchecked.
    connect_timeout : how long ``open`` waits for the calibration and the first record, s.
    reconnect_delay : pynetft's first reconnect delay, s (it doubles while the sensor stays silent).
    health_interval : the health counters are recorded as an event at most this often, s.
    clock_slew_ppm : how fast the device-clock offset may rise (:class:`DeviceClock`), ppm.
    queue_size : records pynetft keeps between reads (the oldest go first when it is full).
    """

    def __init__(
        self,
        address: str = "192.168.1.1",
        rdt_port: int = RDT_PORT,
        http_port: int = 80,
        rate_hz: float = FT_RATE_HZ,
        ft_rate_hz: float = FT_RATE_HZ,
        receiver: str = "hapticlab",
        receive_timeout: float = 0.1,
        counts_per_force: float | None = None,
        counts_per_torque: float | None = None,
        force_unit: str | None = None,
        torque_unit: str | None = None,
        recovery: str = "reconnect",
        range_force: float | list[float] | None = None,
        range_torque: float | list[float] | None = None,
        connect_timeout: float = 2.0,
        reconnect_delay: float = 0.002,
        health_interval: float = 1.0,
        clock_slew_ppm: float = 200.0,
        queue_size: int = 65536,
    ):
        if not isinstance(address, str) or not address.strip():
            raise OptionError("address", f"must be the sensor's IP address or host name, got {address!r}")
        self.address = address.strip()
        self.rdt_port, self.http_port = (
            integer(key, port, minimum=1, maximum=65535, hint=" (a port number)")
            for key, port in (("rdt_port", rdt_port), ("http_port", http_port))
        )
        ft_rate_hz = number("ft_rate_hz", ft_rate_hz, above=0, hint=" Hz")
        self.rate_hz = number(
            "rate_hz", rate_hz, above=0, maximum=ft_rate_hz, hint=" Hz (the RDT rate cannot exceed ft_rate_hz)"
        )
        self.receive_timeout, self.connect_timeout, self.reconnect_delay, health_interval = (
            number(key, value, above=0, hint=" s")
            for key, value in (
                ("receive_timeout", receive_timeout),
                ("connect_timeout", connect_timeout),
                ("reconnect_delay", reconnect_delay),
                ("health_interval", health_interval),
            )
        )
        clock_slew_ppm = number("clock_slew_ppm", clock_slew_ppm, minimum=0, hint=" ppm")
        self.queue_size = integer("queue_size", queue_size, minimum=1)
        self.recovery = choice("recovery", recovery, ("reconnect", "fail_stop"))
        self.receiver = choice("receiver", receiver, RECEIVERS)
        self.latency_s = NETWORK_LATENCY_S
        self.health_interval_ns = int(health_interval * 1e9)
        self.override = _calibration_override(counts_per_force, counts_per_torque, force_unit, torque_unit)
        self.range_force_S = rated_range("range_force", range_force)
        """(3,) rated range per force axis, N (HasRange; inf: unchecked)."""
        self.range_torque_S = rated_range("range_torque", range_torque)
        """(3,) rated range per torque axis, N·m."""
        self.calibration: dict[str, str] = {
            "sensor": "ATI Net F/T",
            "address": self.address,
            "source": "override" if self.override else "sensor (netftapi2.xml)",
        }
        """The calibration in use (HasCalibration); completed by ``open`` with what the sensor reports."""
        if self.override is not None:
            self.calibration.update(self.override.fields())
        self.clock = DeviceClock(ft_rate_hz, clock_slew_ppm)
        self._link: HapticlabLink | PynetftLink | None = None
        self._scale = np.ones(6)  # N or N·m per value the link hands over (a count, or a sensor unit): set by open
        self._pending = NO_WRENCHES  # received, not yet handed out
        self._events: list[Event] = []
        self._word = 0  # the last status word
        self._last_received_ns = 0
        self._silent_since_ns = 0  # the last record, or the last start request sent again
        self._timed_out = False
        self._counters = dict.fromkeys(HEALTH_COUNTERS, 0)
        self._recorded_counters = dict(self._counters)
        self._next_health_ns = 0

    # ------------------------------------------------------------------ life cycle

    def open(self, t0_ns: int) -> None:
        """Fetch the calibration, start the RDT stream and wait for its first record.

        Raises ConnectionError naming the sensor and what the receiver saw when there is no record
        within ``connect_timeout``.
        """
        link = HapticlabLink(self) if self.receiver == "hapticlab" else PynetftLink(self)
        product, calibration = link.open()
        self._link = link
        # pynetft hands over values in the sensor's units (N or lbf ..., N·m or N·mm ...), ours counts
        self._scale = (
            np.repeat([FORCE_UNITS[calibration.force_unit], TORQUE_UNITS[calibration.torque_unit]], 3)
            if link.scaled
            else calibration.si_per_count()
        )
        self.calibration.update({"product": product, **calibration.fields()})
        self._events.append(
            Event(
                t0_ns,
                "sensor_calibration",
                f"Net F/T {self.address}: {calibration.counts_per_force:g} counts/"
                f"{calibration.force_unit}, {calibration.counts_per_torque:g} counts/"
                f"{calibration.torque_unit} ({self.calibration['source']})",
                dict(self.calibration),
            )
        )
        self._next_health_ns = t0_ns + self.health_interval_ns
        self._last_received_ns = self._silent_since_ns = time.monotonic_ns()

    def close(self) -> None:
        """Stop the stream (the RDT stop request); the final counters become an event."""
        if self._link is None:
            return
        self._counters.update(self._link.counters())
        self._link.close()
        self._link = None
        self._health_event(time.monotonic_ns(), final=True)

    # ------------------------------------------------------------------ the stream

    def read(self, until_ns: int) -> list[WrenchSample]:
        """Every sample received and not yet returned whose time is <= ``until_ns``, in time order
        (read-only arrays)."""
        return self.read_block(until_ns).samples()

    def read_block(self, until_ns: int) -> WrenchBlock:
        """:meth:`read` as arrays (ReadsBlocks): the loop's way in, no record per sample."""
        if self._link is None:
            raise RuntimeError("read() before open()")
        batch = self._link.poll()
        if batch is not None:
            self._convert(batch)
        self._watch(until_ns)
        due, self._pending = self._pending.split(until_ns)
        return due

    def _convert(self, batch: RdtBatch) -> None:
        """A batch as a WrenchBlock (SI units, device time, stream status), onto the pending readings."""
        received: Any = batch.received_ns  # one time for the batch (hapticlab) or one per record (pynetft)
        at = (lambda i: received) if np.ndim(received) == 0 else (lambda i: int(received[i]))
        if batch.restarts:
            pieces, start = [], 0
            for i, old, new in batch.restarts:  # the sensor restarted its counter: a new clock from there on
                if i > start:
                    pieces.append(
                        self.clock.stamp_many(
                            batch.k[start:i], received if np.ndim(received) == 0 else received[start:i]
                        )
                    )
                self.clock.reset()
                self._events.append(
                    Event(
                        at(i),
                        "sensor_restart",
                        f"Net F/T {self.address} restarted its sample counter ({old} -> {new}): time re-anchored",
                    )
                )
                start = i
            pieces.append(
                self.clock.stamp_many(batch.k[start:], received if np.ndim(received) == 0 else received[start:])
            )
            t_ns = np.concatenate(pieces)
        elif len(batch.k) <= 16 and np.ndim(received) == 0:  # a usual tick: 16 scalar steps beat 10 array calls
            stamp = self.clock.stamp
            t_ns = np.array([stamp(k, received) for k in batch.k.tolist()])
        else:
            t_ns = self.clock.stamp_many(batch.k, received)
        words = batch.status
        if words.any() or self._word:
            bits = stream_status_array(words).tolist()
            for i in np.flatnonzero(words != np.concatenate([[self._word], words[:-1]])).tolist():
                self._status_event(at(i), int(words[i]))
        else:
            bits = [0] * len(words)
        wrench_S = batch.values * self._scale  # (n, 6) N and N·m
        block = WrenchBlock(
            np.asarray(t_ns, dtype=np.int64),
            np.ascontiguousarray(wrench_S[:, :3]),
            np.ascontiguousarray(wrench_S[:, 3:]),
            np.asarray(batch.k, dtype=np.int64),
            np.asarray(bits, dtype=np.int64),
        )
        self._pending = WrenchBlock.concatenate([self._pending, block]) if len(self._pending) else block
        self._last_received_ns = self._silent_since_ns = at(len(words) - 1)

    def _status_event(self, t_ns: int, word: int) -> None:
        previous, self._word = self._word, word
        description = f"0x{word:08x}: {describe_status(word)}"
        self._events.append(
            status_event(t_ns, f"Net F/T {self.address}", word, previous, stream_status(word), description)
        )

    def _watch(self, now_ns: int) -> None:
        """Receive timeout and health counters: events when they change."""
        mono_ns = time.monotonic_ns()
        silent_ns = mono_ns - self._last_received_ns
        timeout_ns = self.receive_timeout * 1e9
        if not self._timed_out and silent_ns > timeout_ns:
            self._timed_out = True
            self._link.on_timeout()  # type: ignore[union-attr]  # open() made it
            self._events.append(
                Event(
                    now_ns,
                    "sensor_timeout",
                    f"no Net F/T record from {self.address} for {silent_ns * 1e-6:.0f} ms: "
                    f"no sensor data, haptic force held at zero"
                    + ("; reconnecting" if self.recovery == "reconnect" else ""),
                    {"silent_s": silent_ns * 1e-9},
                )
            )
            if self.recovery == "fail_stop" and self.receiver == "hapticlab":
                raise ConnectionError(f"Net F/T {self.address} stopped: no record for {silent_ns * 1e-6:.0f} ms")
        elif self._timed_out and silent_ns <= timeout_ns:
            self._timed_out = False
            self._events.append(Event(now_ns, "sensor_resumed", f"Net F/T {self.address} records again"))
        if self._timed_out and mono_ns - self._silent_since_ns > timeout_ns:
            self._silent_since_ns = mono_ns
            self._link.restart()  # type: ignore[union-attr]  # open() made it; hapticlab: the start request again (pynetft reconnects by itself)
        if now_ns >= self._next_health_ns:
            self._next_health_ns = now_ns + self.health_interval_ns
            self._counters.update(self._link.counters())  # type: ignore[union-attr]  # open() made it
            self._health_event(now_ns)

    def _health_event(self, t_ns: int, final: bool = False) -> None:
        """The counters as an event when a fault counter moved (or at the end of the stream)."""
        faults = self._counters.keys() - {"received"}
        who = f"Net F/T {self.address}"
        event = health_event(t_ns, who, self._counters, self._recorded_counters, faults, final)
        if event is not None:
            self._recorded_counters = dict(self._counters)
            self._events.append(event)

    # ------------------------------------------------------------------ capabilities

    def health_counters(self) -> dict[str, int]:
        """The stream's health counters since ``open`` (:data:`HEALTH_COUNTERS`), as of the last update.

        ``receiver = "hapticlab"``: :data:`.rdt.COUNTER_DOC`. A record that arrives after a
        later one is ``out_of_order``; it is delivered in order if it came in the same read, else
        it is ``late`` (and its rdt_sequence counted ``lost``). A duplicated datagram is a
        ``duplicate`` only. ``receiver = "pynetft"``: pynetft's counting, where such a record
        is always ``lost`` at its gap, then ``out_of_order`` and ``ft_backward``, and a duplicate
        is also a ``stall``; ``late`` stays 0. Neither delivers duplicate, late or stalled records.
        """
        if self._link is not None:
            self._counters.update(self._link.counters())
        return dict(self._counters)

    def drain_events(self) -> list[Event]:
        """Calibration, status changes, timeouts and health since the last call (EmitsEvents)."""
        events, self._events = self._events, []
        return events


def _calibration_override(cpf, cpt, force_unit, torque_unit) -> Calibration | None:
    """The calibration the config gives instead of the sensor's: all four keys or none."""
    given = {"counts_per_force": cpf, "counts_per_torque": cpt, "force_unit": force_unit, "torque_unit": torque_unit}
    if all(v is None for v in given.values()):
        return None
    missing = [k for k, v in given.items() if v is None]
    if missing:
        raise OptionError(
            missing[0],
            "must be given too, got none: a calibration override needs counts_per_force, counts_per_torque, "
            "force_unit and torque_unit together",
        )
    return Calibration.checked(cpf, cpt, force_unit, torque_unit)


@hookimpl
def register_sensors(register):
    """Register the ATI Net F/T as ``netft``."""
    register("netft", NetFTSensor)
