"""The ``netft`` sensor: an ATI Net F/T (or anything speaking its RDT protocol) over UDP.

The wire, the calibration and the stream's health are `pynetft`'s (ATI's RDT
client: it fetches ``netftapi2.xml`` for the counts per unit and units, sends
the RDT start/stop/bias requests on a UDP socket *connected* to the sensor, so
the kernel drops datagrams from any other address, and counts lost,
duplicate, out-of-order and stalled records, reconnecting on a timeout).
What it does not do, this module does:

* **SI units**: pynetft scales counts into the sensor's configured units
  (often N and N·mm); here they become N and N·m.
* **The device clock**: each record carries ``ft_sequence``, the Net F/T's
  internal sample counter (7000/s, decimated with the RDT rate); it is
  unwrapped past 2³² (and is the sample's ``seq``) and mapped onto the session's
  monotonic clock by :class:`DeviceClock`, so sample times are the device's,
  without the network's jitter.
* **Status**: the 32-bit ATI status word becomes the stream's
  ``STATUS_SATURATED`` / ``STATUS_DEVICE_ERROR`` bits, and an event names
  its bits whenever it changes.
* **Health** (:meth:`NetFTSensor.health_counters`) and **events**: the
  counters when they change (at most once per ``health_interval``), a
  receive timeout (the loop then has no sensor data: the haptic force is
  held at zero) and the stream's return.

pynetft receives on its own thread into a bounded queue; ``read`` drains it.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pynetft

from ...core import hookimpl
from ...core.plugins import ConfigError
from ...core.types import STATUS_DEVICE_ERROR, STATUS_OK, STATUS_SATURATED, Event, WrenchSample

FT_RATE_HZ = 7000.0
"""The Net F/T's internal sample rate: ``ft_sequence`` counts at this rate, Hz."""
RDT_PORT = 49152
"""The RDT protocol's UDP port."""

FORCE_UNITS: dict[str, float] = {"N": 1.0, "kN": 1000.0, "lbf": 4.4482216152605, "klbf": 4448.2216152605,
                                 "kgf": 9.80665}
"""N per force unit, by the spelling ``scfgfu`` uses."""
TORQUE_UNITS: dict[str, float] = {"N-m": 1.0, "Nm": 1.0, "N-mm": 1e-3, "Nmm": 1e-3, "kN-m": 1000.0,
                                  "lbf-in": 0.1129848290276167, "lbf-ft": 1.3558179483314004,
                                  "kgf-cm": 0.0980665, "kg-cm": 0.0980665}
"""N·m per torque unit, by the spellings ``scfgtu`` uses."""

# The ATI status word (Net F/T manual, "System Status Code"). Bit 31 summarises every error bit.
ATI_ERROR_SUMMARY = 0x8000_0000
ATI_SATURATION = 0x0002_0000
"""Transducer saturation or A/D error: the reading is clipped or no number at all."""
ATI_MONITOR_LATCHED = 0x0001_0000
"""A threshold monitor condition latched (the user's own thresholds; the reading itself is good)."""
ATI_STATUS_BITS: dict[int, str] = {
    30: "CPU or RAM error", 29: "digital board error", 28: "analog board error",
    27: "serial link error", 26: "program memory check failed", 25: "halted on configuration errors",
    24: "settings validation error", 23: "configuration does not fit the calibration",
    22: "network communication failure", 21: "CAN error", 20: "RDT communication error",
    19: "EtherNet/IP failure", 18: "DeviceNet failure", 17: "transducer saturation or A/D error",
    16: "monitor condition latched", 14: "watchdog timeout", 13: "stack check error",
    12: "serial EEPROM failure", 11: "serial flash failure", 10: "analog board watchdog timeout",
    9: "strain gage excitation current too high", 8: "strain gage excitation current too low",
    7: "artificial analog ground out of range", 6: "analog supply too high", 5: "analog supply too low",
    4: "serial link data unavailable", 3: "reference voltage or power monitor error",
    2: "internal temperature error", 1: "HTTP failure",
}
"""What each bit of the status word says (bit 31 is the error summary)."""

HEALTH_COUNTERS = ("received", "lost", "duplicate", "out_of_order", "stall", "ft_backward", "ft_restart",
                   "malformed", "timeout", "reconnect", "device_error", "warning", "queue_dropped",
                   "calibration_change")
"""The stream's health counters (:meth:`NetFTSensor.health_counters`), counts since ``open``."""


def stream_status(word: int) -> int:
    """The stream's status bits (``core.types``) for an ATI status word.

    Saturation (bit 17) is ``STATUS_SATURATED``; any other error bit, or the
    summary bit alone, is ``STATUS_DEVICE_ERROR``. A latched threshold monitor
    (bit 16) with the summary is a warning about the user's thresholds, not a
    bad reading: ``STATUS_OK``.
    """
    bits = STATUS_SATURATED if word & ATI_SATURATION else STATUS_OK
    if word & ~(ATI_ERROR_SUMMARY | ATI_SATURATION | ATI_MONITOR_LATCHED):
        bits |= STATUS_DEVICE_ERROR
    elif word == ATI_ERROR_SUMMARY:
        bits |= STATUS_DEVICE_ERROR
    return bits


def describe_status(word: int) -> str:
    """The status word in words ("healthy" when 0)."""
    if word == 0:
        return "healthy"
    names = [name for bit, name in ATI_STATUS_BITS.items() if word & (1 << bit)]
    if word & ATI_ERROR_SUMMARY and not names:
        names = ["error summary"]
    return ", ".join(names) or f"unknown bits 0x{word:08x}"


class DeviceClock:
    """Maps a device's sample counter onto the session's monotonic clock, ns.

    The counter ``k`` runs at ``rate_hz`` on the device's crystal; a sample's
    receive time is its device time plus a latency that is never negative and
    often near its minimum. So the offset between the two clocks is the lower
    envelope of ``received_ns − k·1e9/rate_hz``: it follows every new minimum at
    once, and may rise at ``slew_ppm`` of the elapsed device time (the device's
    crystal running fast against the host's, ≤ ~100 ppm for a crystal). A
    sample's time is ``k·1e9/rate_hz + offset``: never later than its receipt,
    spaced by the device's own clock, and non-decreasing (a lower envelope that
    drops by more than one sample period is held to the previous time + 1 ns).

    Parameters
    ----------
    rate_hz : the counter's rate, Hz.
    slew_ppm : fastest rise of the offset, parts per million of device time.
    """

    def __init__(self, rate_hz: float = FT_RATE_HZ, slew_ppm: float = 200.0):
        self.period_ns = 1e9 / rate_hz
        self.slew = slew_ppm * 1e-6
        self.offset_ns: float | None = None
        self.last_k: int | None = None
        self.last_t_ns: int | None = None

    def reset(self) -> None:
        """Forget the mapping (the device restarted its counter)."""
        self.offset_ns = self.last_k = self.last_t_ns = None

    def stamp(self, k: int, received_ns: int) -> int:
        """The session time of device sample ``k`` (unwrapped counter) received at ``received_ns``, ns."""
        device_ns = k * self.period_ns
        seen = received_ns - device_ns
        if self.offset_ns is None:
            self.offset_ns = seen
        else:
            self.offset_ns = min(seen, self.offset_ns + self.slew * (k - self.last_k) * self.period_ns)
        self.last_k = k
        t_ns = int(round(device_ns + self.offset_ns))
        if self.last_t_ns is not None and t_ns <= self.last_t_ns:
            t_ns = self.last_t_ns + 1
        self.last_t_ns = t_ns
        return t_ns


class NetFTSensor:
    """An ATI Net F/T sensor over RDT/UDP (SensorSource, EmitsEvents, HasCalibration, HasRange, ReportsHealth).

    Parameters
    ----------
    address : the sensor's IP address or host name.
    rdt_port : its RDT UDP port.
    http_port : its HTTP port (``netftapi2.xml``: the calibration).
    rate_hz : the RDT output rate set on the sensor (``comrdtrate``), Hz: the loop's stale timeout.
    ft_rate_hz : the rate ``ft_sequence`` counts at (7000 on every Net F/T), Hz.
    receive_timeout : no record for this long is a timeout: an event, and pynetft reconnects, s.
    counts_per_force, counts_per_torque, force_unit, torque_unit : a calibration overriding the
        sensor's (all four or none): counts per force unit, per torque unit, and the units
        (``N``, ``lbf``, ... and ``N-m``, ``N-mm``, ``lbf-in``, ...).
    recovery : ``"reconnect"`` (keep trying after a timeout or a fault) or ``"fail_stop"`` (the first
        fault ends the stream: ``read`` raises and the session ends).
    range_force, range_torque : the sensor's rated range per axis (a number or 3), N and N·m; a
        reading beyond it with a good status is refused as implausible. Default: unchecked.
    connect_timeout : how long ``open`` waits for the calibration and the first record, s.
    health_interval : the health counters are recorded as an event at most this often, s.
    clock_slew_ppm : how fast the device-clock offset may rise (:class:`DeviceClock`), ppm.
    queue_size : records pynetft keeps between reads (the oldest go first when it is full).
    """

    def __init__(self, address: str = "192.168.1.1", rdt_port: int = RDT_PORT, http_port: int = 80,
                 rate_hz: float = FT_RATE_HZ, ft_rate_hz: float = FT_RATE_HZ, receive_timeout: float = 0.1,
                 counts_per_force: float | None = None, counts_per_torque: float | None = None,
                 force_unit: str | None = None, torque_unit: str | None = None, recovery: str = "reconnect",
                 range_force: float | list[float] | None = None, range_torque: float | list[float] | None = None,
                 connect_timeout: float = 2.0, reconnect_delay: float = 0.002, health_interval: float = 1.0,
                 clock_slew_ppm: float = 200.0,
                 queue_size: int = 65536):
        if not isinstance(address, str) or not address.strip():
            raise ConfigError(f"sensor.address: must be the sensor's IP address or host name, got {address!r}")
        for key, port in (("rdt_port", rdt_port), ("http_port", http_port)):
            if not 0 < port < 65536:
                raise ConfigError(f"sensor.{key}: must be a port number 1..65535, got {port!r}")
        for key, value in (("rate_hz", rate_hz), ("ft_rate_hz", ft_rate_hz), ("receive_timeout", receive_timeout),
                           ("connect_timeout", connect_timeout), ("reconnect_delay", reconnect_delay),
                           ("health_interval", health_interval)):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"sensor.{key}: must be a finite number > 0, got {value!r}")
        if not rate_hz <= ft_rate_hz:
            raise ConfigError(f"sensor.rate_hz: the RDT rate cannot exceed ft_rate_hz ({ft_rate_hz:g} Hz), "
                              f"got {rate_hz!r}")
        if not (math.isfinite(clock_slew_ppm) and clock_slew_ppm >= 0):
            raise ConfigError(f"sensor.clock_slew_ppm: must be a finite number >= 0, got {clock_slew_ppm!r}")
        if queue_size < 1:
            raise ConfigError(f"sensor.queue_size: must be >= 1, got {queue_size!r}")
        if recovery not in ("reconnect", "fail_stop"):
            raise ConfigError(f"sensor.recovery: must be \"reconnect\" or \"fail_stop\", got {recovery!r}")
        self.address, self.rdt_port, self.http_port = address.strip(), int(rdt_port), int(http_port)
        self.rate_hz = float(rate_hz)
        self.receive_timeout = float(receive_timeout)
        self.connect_timeout = float(connect_timeout)
        self.reconnect_delay = float(reconnect_delay)
        self.recovery = recovery
        self.queue_size = int(queue_size)
        self.health_interval_ns = int(health_interval * 1e9)
        self.override = _calibration_override(counts_per_force, counts_per_torque, force_unit, torque_unit)
        self.range_force_S = _range("range_force", range_force)
        """(3,) rated range per force axis, N (HasRange; inf: unchecked)."""
        self.range_torque_S = _range("range_torque", range_torque)
        """(3,) rated range per torque axis, N·m."""
        self.calibration: dict[str, str] = {"sensor": "ATI Net F/T", "address": self.address,
                                            "source": "override" if self.override else "sensor (netftapi2.xml)"}
        """The calibration in use (HasCalibration); completed by ``open`` with what the sensor reports."""
        if self.override is not None:
            self.calibration.update(_calibration_fields(self.override))
        self.clock = DeviceClock(ft_rate_hz, clock_slew_ppm)
        self._client: pynetft.Client | None = None
        self._si_per_unit = np.ones(6)  # N per force unit (×3), N·m per torque unit (×3): set by open
        self._pending: list[WrenchSample] = []
        self._events: list[Event] = []
        self._raw_ft: int | None = None  # the last ft_sequence as sent (uint32)
        self._k = 0  # the unwrapped ft_sequence (the first one as sent)
        self._word = 0  # the last status word
        self._last_received_ns: int | None = None
        self._timed_out = False
        self._counters = dict.fromkeys(HEALTH_COUNTERS, 0)
        self._recorded_counters = dict(self._counters)
        self._next_health_ns = 0

    # ------------------------------------------------------------------ life cycle

    def open(self, t0_ns: int) -> None:
        """Fetch the calibration, start the RDT stream and wait for its first record.

        Raises ConnectionError naming the sensor and what pynetft saw when there is no record
        within ``connect_timeout``.
        """
        config = pynetft.Config(
            sensor_host=self.address, rdt_port=self.rdt_port, http_port=self.http_port,
            receive_timeout=self.receive_timeout, configuration_timeout=self.connect_timeout,
            configuration_connect_timeout=min(0.5, self.connect_timeout),
            reconnect_initial_delay=self.reconnect_delay, reconnect_max_delay=max(5.0, self.reconnect_delay),
            deliver_samples_with_error_status=True,  # saturation must reach the stream, not vanish
            recovery_policy=pynetft.RecoveryPolicy.RECONNECT if self.recovery == "reconnect"
            else pynetft.RecoveryPolicy.FAIL_STOP,
            calibration_override=self.override)
        self._client = pynetft.Client(config, queue_size=self.queue_size)
        self._client.start()
        if not self._client.wait_for_first_sample(self.connect_timeout):
            health = self._client.health()
            self._client.stop()
            self._client = None
            raise ConnectionError(f"no Net F/T record from {self.address}:{self.rdt_port} within "
                                  f"{self.connect_timeout:g} s ({health.last_error or health.state.value})")
        configuration = self._client.health().sensor_configuration
        calibration = configuration.calibration
        self._si_per_unit = np.repeat([FORCE_UNITS[calibration.force_unit.value],
                                       TORQUE_UNITS[calibration.torque_unit.value]], 3)
        self.calibration.update({"product": configuration.product_name, **_calibration_fields(calibration)})
        self._events.append(Event(t0_ns, "sensor_calibration",
                                  f"Net F/T {self.address}: {calibration.counts_per_force_unit:g} counts/"
                                  f"{calibration.force_unit.value}, {calibration.counts_per_torque_unit:g} counts/"
                                  f"{calibration.torque_unit.value} ({self.calibration['source']})",
                                  dict(self.calibration)))
        self._next_health_ns = t0_ns + self.health_interval_ns
        self._last_received_ns = time.monotonic_ns()

    def close(self) -> None:
        """Stop the stream (pynetft sends the RDT stop request); the final counters become an event."""
        if self._client is None:
            return
        self._update_counters()
        self._client.stop()
        self._client = None
        self._health_event(time.monotonic_ns(), final=True)

    # ------------------------------------------------------------------ the stream

    def read(self, until_ns: int) -> list[WrenchSample]:
        """Every sample received and not yet returned whose time is <= ``until_ns``, in time order."""
        if self._client is None:
            raise RuntimeError("read() before open()")
        batch: list[pynetft.Sample] = []
        try:
            for sample in self._client.samples(timeout=0.0):
                batch.append(sample)
        except TimeoutError:  # nothing more queued
            pass
        except pynetft.SensorFaultError as exc:  # fail_stop: the stream is over
            raise ConnectionError(f"Net F/T {self.address} stopped: {exc.fault_code.value} "
                                  f"({exc.health.last_error})") from None
        if batch:
            self._convert(batch)
        self._watch(until_ns)
        if not self._pending or self._pending[0].t_ns > until_ns:
            return []
        if self._pending[-1].t_ns <= until_ns:
            out, self._pending = self._pending, []
            return out
        cut = next(i for i, s in enumerate(self._pending) if s.t_ns > until_ns)
        out, self._pending = self._pending[:cut], self._pending[cut:]
        return out

    def _convert(self, batch: list[pynetft.Sample]) -> None:
        """pynetft samples as WrenchSamples (SI units, device time, stream status), onto the pending list."""
        wrench_S = np.array([sample.wrench for sample in batch]) * self._si_per_unit  # (n, 6) N and N·m
        wrench_S.setflags(write=False)
        for sample, row in zip(batch, wrench_S):
            ft = sample.ft_sequence
            if self._raw_ft is None:
                self._k = ft
            else:
                step = (ft - self._raw_ft) % 2**32
                if step >= 2**31:  # pynetft delivers a backward ft_sequence only as a device restart
                    self.clock.reset()
                    self._events.append(Event(sample.received_at_ns, "sensor_restart",
                                              f"Net F/T {self.address} restarted its sample counter "
                                              f"({self._raw_ft} -> {ft}): time re-anchored"))
                    step = 1
                self._k += step
            self._raw_ft = ft
            if sample.status != self._word:
                self._status_event(sample.received_at_ns, sample.status)
            self._pending.append(WrenchSample(t_ns=self.clock.stamp(self._k, sample.received_at_ns),
                                              force_S=row[:3], torque_S=row[3:], seq=self._k,
                                              status=stream_status(sample.status)))
        self._last_received_ns = batch[-1].received_at_ns

    def _status_event(self, t_ns: int, word: int) -> None:
        previous, self._word = self._word, word
        bits = stream_status(word)
        kind = "sensor_status_ok" if word == 0 else "sensor_saturated" if bits & STATUS_SATURATED else \
            "sensor_error" if bits else "sensor_warning"
        self._events.append(Event(t_ns, kind, f"Net F/T {self.address} status 0x{word:08x}: {describe_status(word)}",
                                  {"status_word": word, "previous_status_word": previous, "stream_status": bits}))

    def _watch(self, now_ns: int) -> None:
        """Receive timeout and health counters: events when they change."""
        silent_ns = time.monotonic_ns() - self._last_received_ns
        if not self._timed_out and silent_ns > self.receive_timeout * 1e9:
            self._timed_out = True
            self._events.append(Event(now_ns, "sensor_timeout",
                                      f"no Net F/T record from {self.address} for {silent_ns * 1e-6:.0f} ms: "
                                      f"no sensor data, haptic force held at zero"
                                      + ("; reconnecting" if self.recovery == "reconnect" else ""),
                                      {"silent_s": silent_ns * 1e-9}))
        elif self._timed_out and silent_ns <= self.receive_timeout * 1e9:
            self._timed_out = False
            self._events.append(Event(now_ns, "sensor_resumed", f"Net F/T {self.address} records again"))
        if now_ns >= self._next_health_ns:
            self._next_health_ns = now_ns + self.health_interval_ns
            self._update_counters()
            self._health_event(now_ns)

    def _update_counters(self) -> None:
        h = self._client.health()
        self._counters.update(
            received=h.received_count, lost=h.lost_count, duplicate=h.duplicate_count,
            out_of_order=h.out_of_order_count, stall=h.ft_stall_count, ft_backward=h.ft_backward_count,
            ft_restart=h.ft_restart_count, malformed=h.malformed_count, timeout=h.timeout_count,
            reconnect=h.reconnect_count, device_error=h.device_error_count, warning=h.warning_count,
            queue_dropped=h.python_queue_dropped_count, calibration_change=h.calibration_change_count)

    def _health_event(self, t_ns: int, final: bool = False) -> None:
        """The counters as an event when a fault counter moved (or at the end of the stream)."""
        changed = {k: v - self._recorded_counters[k] for k, v in self._counters.items()
                   if k != "received" and v != self._recorded_counters[k]}
        if not changed and not final:
            return
        self._recorded_counters = dict(self._counters)
        what = ", ".join(f"{k} +{v}" for k, v in changed.items()) or "no faults"
        self._events.append(Event(t_ns, "sensor_health", f"Net F/T {self.address}: {what}"
                                  + (" (stream closed)" if final else ""), dict(self._counters)))

    # ------------------------------------------------------------------ capabilities

    def health_counters(self) -> dict[str, int]:
        """The stream's health counters since ``open`` (:data:`HEALTH_COUNTERS`), as of the last update.

        pynetft's counting: ``lost`` is records missing at a gap in rdt_sequence (a
        record that arrives after a later one was counted there and is then also an
        ``out_of_order`` and an ``ft_backward``); ``stall`` counts records repeating
        the previous record's ft_sequence, so a duplicated datagram is a ``duplicate``
        and a ``stall``. None of these records is delivered.
        """
        if self._client is not None:
            self._update_counters()
        return dict(self._counters)

    def drain_events(self) -> list[Event]:
        """Calibration, status changes, timeouts and health since the last call (EmitsEvents)."""
        events, self._events = self._events, []
        return events


def _calibration_override(cpf, cpt, force_unit, torque_unit) -> pynetft.Calibration | None:
    """The calibration the config gives instead of the sensor's: all four keys or none."""
    given = {"counts_per_force": cpf, "counts_per_torque": cpt, "force_unit": force_unit, "torque_unit": torque_unit}
    if all(v is None for v in given.values()):
        return None
    missing = [k for k, v in given.items() if v is None]
    if missing:
        raise ConfigError(f"sensor.{missing[0]}: a calibration override needs counts_per_force, counts_per_torque, "
                          f"force_unit and torque_unit together")
    for key in ("counts_per_force", "counts_per_torque"):
        if not (math.isfinite(given[key]) and given[key] > 0):
            raise ConfigError(f"sensor.{key}: must be a finite number of counts > 0, got {given[key]!r}")
    if force_unit not in FORCE_UNITS:
        raise ConfigError(f"sensor.force_unit: one of {', '.join(FORCE_UNITS)}, got {force_unit!r}")
    if torque_unit not in TORQUE_UNITS:
        raise ConfigError(f"sensor.torque_unit: one of {', '.join(TORQUE_UNITS)}, got {torque_unit!r}")
    spelled = {"Nm": "N-m", "Nmm": "N-mm", "kg-cm": "kgf-cm"}.get(torque_unit, torque_unit)
    return pynetft.Calibration(float(cpf), float(cpt), pynetft.ForceUnit(force_unit), pynetft.TorqueUnit(spelled))


def _calibration_fields(calibration: pynetft.Calibration) -> dict[str, str]:
    return {"counts_per_force": f"{calibration.counts_per_force_unit:g}",
            "counts_per_torque": f"{calibration.counts_per_torque_unit:g}",
            "force_unit": calibration.force_unit.value, "torque_unit": calibration.torque_unit.value}


def _range(key: str, value: float | list[float] | None) -> np.ndarray:
    if value is None:
        return np.full(3, np.inf)
    array = np.broadcast_to(np.asarray(value, dtype=float), 3) if np.ndim(value) == 0 else np.asarray(value, float)
    if array.shape != (3,) or not (array > 0).all():
        raise ConfigError(f"sensor.{key}: must be a number or 3 numbers > 0, got {value!r}")
    return array.copy()


@hookimpl
def register_sensors(register):
    """Register the ATI Net F/T as ``netft``."""
    register("netft", NetFTSensor)
