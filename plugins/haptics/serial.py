"""``serial``: a haptic master on a serial port (USB CDC, UART), in one of two wire protocols.

``protocol = "hapticlab"``: our framed binary protocol for DIY and Arduino
masters (``framing.py``, specified in ``docs/serial-protocol.md``, device side
in ``firmware/hapticlab_master/``). ``protocol = "inverse3"``: the Haply
Inverse3's own serial protocol (``inverse3.py``).

Each ``send`` is one request/reply exchange on the wire: the force goes out,
the device answers with the handle's state, which ``state()`` then returns.
With ``wait_for_reply = false`` (our protocol only) ``send`` writes the force
and takes the replies that have already come (matched by sequence number),
so the loop never waits on the wire; the state is then a tick or two old.
What reaches the wire is never above the device's maximum force
(``device_max_force``, and for our protocol also the maximum the device reports
in its handshake) and never a NaN: a non-finite command is written as zero, a
disabled one as zero, a larger one is scaled down along its direction.

A lost device raises from ``send`` (the session's loop then zeroes the force and
records an event, and goes on; the plugin itself writes a zero force at once
when the port still works, and our protocol's device watchdog zeroes it when
nothing more arrives): no reply within ``read_timeout``, a port that
is gone (unplugged: EIO), more than ``max_consecutive_errors`` bad replies in a
row (CRC errors, NAKs, malformed or non-finite replies), or a device that
reports a fault. While lost, ``send`` raises at once without touching the
port, except once every ``reconnect_interval`` when it tries again (reopening
the port if it has gone, redoing the handshake if the device restarted),
writing zero force and waiting for the answer; so a dead device costs the
loop one ``read_timeout`` per ``reconnect_interval``, not one per tick. Losses
and recoveries are events (``haptic_device_lost``, ``haptic_device_back``), so
are changes of the link's counters (``haptic_link``) and of the device's status
bits (``haptic_device_status``).

CRTK names: ``servo_cf`` is ``send`` (servo in Cartesian force), ``measured_cp``
is ``state`` (the handle's measured Cartesian pose, with its velocity).
"""

from __future__ import annotations

import math
import select
import time
import typing
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import UserError
from hapticlab.core.host.registry import ConfigError
from hapticlab.core.types import DeviceState, Event, HapticCommand
from hapticlab.plugins.haptics import framing, inverse3

if typing.TYPE_CHECKING:
    import serial as pyserial

PROTOCOLS = ("hapticlab", "inverse3")
IDENTITY_QUAT = np.array([1.0, 0.0, 0.0, 0.0])
ZERO3_F32 = np.zeros(3, np.float32)
CLAMP_MARGIN = 1.0 - 1e-6  # float32 rounding of a force scaled to the limit stays below the limit
STATUS_TEXT = {
    framing.STATUS_WATCHDOG: "its watchdog zeroed the force (no host frame in time)",
    framing.STATUS_CLAMPED: "it clamped a force to its own maximum",
}


class MasterOpenError(UserError, ConnectionError):
    """The master could not be opened or did not answer the handshake; the message names the port and why."""


class MasterLostError(ConnectionError):
    """The master stopped answering, went away, or sent bad replies beyond the limit; the message says which.

    ``cause`` is one of ``"gone"`` (the port failed: unplugged), ``"restarted"``
    (the device forgot the handshake), ``"silent"`` (no reply), ``"errors"``
    (bad replies in a row, a device fault) or ``"lost"`` (still lost, not retried).
    """

    def __init__(self, message: str, cause: str = "silent"):
        super().__init__(message)
        self.cause = cause


@dataclass(frozen=True, slots=True)
class Reading:
    """What one reply says about the handle.

    Attributes:
        p_DoHo_D: (3,) handle position in D, m.
        v_DHo_D: (3,) handle velocity in D, m/s.
        buttons: bit mask of pressed buttons.
        status: device status bits (``framing.STATUS_*``; 0 for the Inverse3).
    """

    p_DoHo_D: np.ndarray
    v_DHo_D: np.ndarray
    buttons: int = 0
    status: int = 0


class SerialPort:
    """A pyserial port that turns every OS-level failure into MasterLostError naming the port."""

    def __init__(self, port: str, baudrate: int, read_timeout: float):
        self.name = port
        try:
            import serial
        except ImportError:
            raise MasterOpenError(
                f"haptic.port {port}: the serial plugin needs pyserial (pip install pyserial)"
            ) from None
        self._serial_exception = serial.SerialException
        try:
            self.serial: pyserial.Serial = serial.Serial(
                port, baudrate, timeout=read_timeout, write_timeout=read_timeout, exclusive=True
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise MasterOpenError(f"haptic.port {port}: cannot open: {_why(exc)}") from None

    def write(self, data: bytes) -> None:
        try:
            self.serial.write(data)
        except (self._serial_exception, OSError) as exc:
            raise MasterLostError(f"{self.name}: write failed: {_why(exc)}", "gone") from None

    def read(self, size: int, deadline: float) -> bytes:
        """Up to ``size`` bytes: those already received, else the first to arrive before ``deadline``
        (monotonic s); b"" when none came. Never waits past the deadline, whatever the port's own timeout."""
        try:
            waiting = self.serial.in_waiting
            if not waiting:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not select.select([self.serial.fileno()], [], [], remaining)[0]:
                    return b""
                waiting = self.serial.in_waiting or 1  # 0 when the other side hung up: read says so
            return self.serial.read(min(size, waiting))
        except (self._serial_exception, OSError) as exc:
            raise MasterLostError(f"{self.name}: read failed: {_why(exc)}", "gone") from None

    def waiting(self) -> int:
        try:
            return self.serial.in_waiting
        except (self._serial_exception, OSError) as exc:
            raise MasterLostError(f"{self.name}: {_why(exc)}", "gone") from None

    def discard_input(self) -> None:
        try:
            self.serial.reset_input_buffer()
        except (self._serial_exception, OSError) as exc:
            raise MasterLostError(f"{self.name}: {_why(exc)}", "gone") from None

    def close(self) -> None:
        try:
            self.serial.close()
        except (self._serial_exception, OSError):
            pass


def _finite(state: framing.State) -> bool:
    """Every number in a STATE is finite (a device's NaN is a bad reply, never a position)."""
    return all(map(math.isfinite, state.p_DoHo_D)) and all(map(math.isfinite, state.v_DHo_D))


def _why(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc) or type(exc).__name__


class MasterLink(Protocol):
    """The host side of one wire protocol over an open port.

    ``handshake(timeout_s)`` wakes the device up and returns one line naming it
    (MasterOpenError on failure); ``max_force`` is then the device's own
    maximum, N, when the protocol reports one (else None). ``exchange(force_D)``
    writes one (3,) float32 force in D, N, and returns the reply's Reading, or
    None for a bad reply (counted in ``counters``); it raises MasterLostError
    when nothing arrives within the read timeout. ``post(force_D)`` writes a
    force without waiting for its reply (the next ``exchange`` skips it).
    """

    max_force: float | None
    counters: dict[str, int]

    def handshake(self, timeout_s: float) -> str: ...
    def exchange(self, force_D: np.ndarray) -> Reading | None: ...
    def post(self, force_D: np.ndarray) -> None: ...


class PipelinedLink(MasterLink, Protocol):
    """A link whose replies can be collected later (``poll``), matched to the forces ``post`` wrote."""

    def poll(self) -> list[Reading | None]: ...


class HapticlabLink:
    """Our framed protocol (``framing.py``): HELLO handshake, FORCE → STATE exchanges, CRC-checked."""

    def __init__(self, port: SerialPort, read_timeout: float, watchdog_s: float):
        self.port, self.read_timeout, self.watchdog_s = port, read_timeout, watchdog_s
        self.decoder = framing.FrameDecoder()
        self.seq = 0
        self.max_force: float | None = None
        self.counters = {"crc_errors": 0, "garbage_bytes": 0, "naks": 0, "stale_replies": 0, "bad_replies": 0}
        self.outstanding: dict[int, float] = {}  # pipelined: seq → when it was sent (monotonic s), oldest first

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFF
        return self.seq

    def _sync_counters(self) -> None:
        self.counters["crc_errors"] = self.decoder.crc_errors
        self.counters["garbage_bytes"] = self.decoder.garbage_bytes

    def handshake(self, timeout_s: float) -> str:
        where = f"haptic.port {self.port.name}"
        deadline = time.monotonic() + timeout_s
        self.port.discard_input()  # a board reset on open prints its boot banner
        received = 0
        while time.monotonic() < deadline:
            seq = self._next_seq()
            self.port.write(framing.encode_frame(framing.HELLO, seq, framing.pack_hello(self.watchdog_s)))
            retry_at = min(deadline, time.monotonic() + 0.1)  # an Arduino may still be in its bootloader
            while time.monotonic() < retry_at:
                data = self.port.read(4096, retry_at)
                received += len(data)
                for frame in self.decoder.feed(data):
                    if (
                        frame.kind == framing.NAK
                        and len(frame.payload) == framing.NAK_FORMAT.size
                        and frame.payload[1] == framing.NAK_VERSION
                    ):  # other NAKs: line noise, try again
                        raise MasterOpenError(
                            f"{where}: the device refused HELLO: it does not speak hapticlab "
                            f"protocol version {framing.PROTOCOL_VERSION}"
                        )
                    if frame.kind == framing.HELLO_ACK and len(frame.payload) == framing.HELLO_ACK_FORMAT.size:
                        ack = framing.HelloAck.unpack(frame.payload)
                        if ack.version != framing.PROTOCOL_VERSION:
                            raise MasterOpenError(
                                f"{where}: the device speaks hapticlab protocol version "
                                f"{ack.version}, this host speaks {framing.PROTOCOL_VERSION}"
                            )
                        if not (math.isfinite(ack.max_force) and ack.max_force > 0):
                            raise MasterOpenError(f"{where}: the device reports a maximum force of {ack.max_force!r} N")
                        self.max_force = ack.max_force
                        self._sync_counters()
                        return (
                            f"hapticlab protocol v{ack.version} device {ack.device_id} firmware "
                            f"{ack.firmware_version}, max {ack.max_force:g} N, {ack.max_rate_hz:g} Hz"
                        )
        self._sync_counters()
        if received:
            raise MasterOpenError(
                f"{where}: {received} byte(s) arrived in {timeout_s:g} s but no hapticlab "
                f"HELLO_ACK ({self.decoder.crc_errors} CRC error(s)): wrong baud rate, "
                'or not a hapticlab master (protocol = "inverse3"?)'
            )
        raise MasterOpenError(
            f"{where}: no reply to the hapticlab HELLO within {timeout_s:g} s "
            "(is the firmware flashed, the baud rate right, the device powered?)"
        )

    def exchange(self, force_D: np.ndarray) -> Reading | None:
        seq = self._next_seq()
        self.outstanding.clear()  # a waited-for exchange supersedes what a pipeline had in flight
        self.port.write(framing.encode_frame(framing.FORCE, seq, framing.pack_force(force_D)))
        return self._await_state(seq)

    # pipelined: write now, collect the replies that have come when next asked --------------------

    def post(self, force_D: np.ndarray) -> None:
        """Write one FORCE without waiting for its STATE."""
        seq = self._next_seq()
        self.outstanding.pop(seq, None)  # a seq 256 commands old is long answered or long lost
        self.outstanding[seq] = time.monotonic()
        self.port.write(framing.encode_frame(framing.FORCE, seq, framing.pack_force(force_D)))

    def poll(self) -> list[Reading | None]:
        """The replies that have arrived, in order, without blocking: a Reading, or None for a bad reply.

        A STATE answers its command and every older one still outstanding; a
        broken frame (CRC) or a NAK stands for the oldest outstanding command.
        Raises MasterLostError when the oldest outstanding command has waited
        longer than the read timeout.
        """
        waiting = self.port.waiting()
        if not waiting and not self.outstanding:
            return []
        errors_before = self.decoder.crc_errors
        frames = self.decoder.feed(self.port.read(waiting, 0.0)) if waiting else []
        outcomes: list[Reading | None] = []
        for _ in range(self.decoder.crc_errors - errors_before):
            outcomes.append(None)
            self._forget_oldest()
        for frame in frames:
            if frame.kind == framing.STATE and len(frame.payload) == framing.STATE_FORMAT.size:
                state = framing.State.unpack(frame.payload)
                if state.ack_seq not in self.outstanding:
                    self.counters["stale_replies"] += 1
                    continue
                while self.outstanding:  # answered, and so are the older ones (their replies are late or lost)
                    seq = next(iter(self.outstanding))
                    del self.outstanding[seq]
                    if seq == state.ack_seq:
                        break
                if _finite(state):
                    outcomes.append(Reading(state.p_DoHo_D, state.v_DHo_D, state.buttons, state.status))
                else:
                    self.counters["bad_replies"] += 1
                    outcomes.append(None)
            elif frame.kind == framing.NAK and len(frame.payload) == framing.NAK_FORMAT.size:
                self.counters["naks"] += 1
                if frame.payload[1] == framing.NAK_NOT_READY:
                    raise MasterLostError(
                        f"{self.port.name}: the device forgot the handshake (restarted?)", "restarted"
                    )
                self.outstanding.pop(frame.payload[0], None) if frame.payload[
                    0
                ] in self.outstanding else self._forget_oldest()
                outcomes.append(None)
            else:
                self.counters["bad_replies"] += 1
        self._sync_counters()
        if self.outstanding:
            waited = time.monotonic() - next(iter(self.outstanding.values()))
            if waited > self.read_timeout:
                self.outstanding.clear()
                raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")
        return outcomes

    def _forget_oldest(self) -> None:
        if self.outstanding:
            del self.outstanding[next(iter(self.outstanding))]

    def _await_state(self, seq: int) -> Reading | None:
        deadline = time.monotonic() + self.read_timeout
        errors_before = self.decoder.crc_errors
        arrived = False
        while True:
            data = self.port.read(4096, deadline)
            arrived |= bool(data)
            for frame in self.decoder.feed(data):
                if frame.kind == framing.STATE and len(frame.payload) == framing.STATE_FORMAT.size:
                    state = framing.State.unpack(frame.payload)
                    if state.ack_seq != seq:
                        self.counters["stale_replies"] += 1
                        continue
                    self._sync_counters()
                    if not _finite(state):
                        self.counters["bad_replies"] += 1
                        return None
                    return Reading(state.p_DoHo_D, state.v_DHo_D, state.buttons, state.status)
                if frame.kind == framing.NAK and len(frame.payload) == framing.NAK_FORMAT.size:
                    self.counters["naks"] += 1
                    self._sync_counters()
                    if frame.payload[1] == framing.NAK_NOT_READY:
                        raise MasterLostError(
                            f"{self.port.name}: the device forgot the handshake (restarted?)", "restarted"
                        )
                    return None
                self.counters["bad_replies"] += 1  # a frame that answers nothing we asked
            self._sync_counters()
            if self.decoder.crc_errors > errors_before and not self.decoder.pending() and not self.port.waiting():
                return None  # the reply came and was broken: no need to wait out the timeout
            if time.monotonic() >= deadline:
                if arrived:
                    self.counters["bad_replies"] += 1
                    return None
                raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")


class Inverse3Link:
    """Haply's Inverse3 protocol (``inverse3.py``): wake-up, then force → end-effector state exchanges."""

    def __init__(self, port: SerialPort, read_timeout: float):
        self.port, self.read_timeout = port, read_timeout
        self.max_force: float | None = None  # the Inverse3 does not report one
        self.counters = {"bad_replies": 0, "truncated_replies": 0}
        self.owed = 0  # replies to posted forces not yet read

    def post(self, force_D: np.ndarray) -> None:
        """Write a force request without reading its reply (the next exchange reads and drops it)."""
        self.port.write(inverse3.pack_force_request(force_D))
        self.owed += 1

    def _read_exactly(self, size: int, deadline: float) -> bytes:
        data = b""
        while len(data) < size:
            chunk = self.port.read(size - len(data), deadline)
            if not chunk:
                break
            data += chunk
        return data

    def handshake(self, timeout_s: float) -> str:
        where = f"haptic.port {self.port.name}"
        deadline = time.monotonic() + timeout_s
        self.port.discard_input()
        reply = b""
        while time.monotonic() < deadline:
            self.port.write(inverse3.WAKEUP_REQUEST)
            reply = self._read_exactly(inverse3.DEVICE_INFO_SIZE, min(deadline, time.monotonic() + 0.5))
            if reply:
                reply += self._read_exactly(inverse3.DEVICE_INFO_SIZE - len(reply), time.monotonic() + 0.05)
                break
        if not reply:
            raise MasterOpenError(
                f"{where}: no reply to the Inverse3 wake-up (0x0A) within {timeout_s:g} s "
                "(is it an Inverse3, powered, and not held by another program?)"
            )
        try:
            info = inverse3.DeviceInfo.unpack(reply)
        except ValueError as exc:
            raise MasterOpenError(f"{where}: not an Inverse3 answer to the wake-up: {exc}") from None
        return (
            f"Haply Inverse3 device {info.device_id} ({info.device_id_ext}), model {info.model}, "
            f"hardware {info.hardware_version}, firmware {info.firmware_version}"
        )

    def exchange(self, force_D: np.ndarray) -> Reading | None:
        self.port.write(inverse3.pack_force_request(force_D))
        owed, self.owed = self.owed, 0
        if owed:  # the replies to posted forces come first: read past them
            self._read_exactly(owed * inverse3.STATE_SIZE, time.monotonic() + self.read_timeout)
        reply = self._read_exactly(inverse3.STATE_SIZE, time.monotonic() + self.read_timeout)
        if not reply:
            raise MasterLostError(f"{self.port.name}: no reply within {self.read_timeout * 1e3:g} ms")
        if len(reply) < inverse3.STATE_SIZE or reply[0] != inverse3.END_EFFECTOR_STATE:
            # no framing to resynchronise on: drop what is in flight, the next exchange starts clean
            self.counters["truncated_replies" if len(reply) < inverse3.STATE_SIZE else "bad_replies"] += 1
            self.port.discard_input()
            return None
        p_DoHo_D, v_DHo_D = inverse3.unpack_state(reply)
        if not (np.isfinite(p_DoHo_D).all() and np.isfinite(v_DHo_D).all()):
            self.counters["bad_replies"] += 1
            return None
        return Reading(p_DoHo_D, v_DHo_D)


def clamp_force(force_D: np.ndarray, max_force: float) -> np.ndarray:
    """(3,) float32 force for the wire: finite, with a norm at most ``max_force`` N, direction kept.

    A force with any non-finite component is zero (nothing but zero can be
    trusted of it); a finite one of any size, up to 1.8e308 N, is scaled down
    along its direction without overflowing (``math.hypot`` scales as it goes).
    Plain floats, not numpy: this runs once a tick on three numbers.
    """
    try:
        x, y, z = (float(v) for v in force_D)
    except (TypeError, ValueError):
        return ZERO3_F32.copy()
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return ZERO3_F32.copy()
    norm = math.hypot(x, y, z)
    if norm > max_force:
        k = max_force * CLAMP_MARGIN / norm
        x, y, z = x * k, y * k, z * k
    return np.array((x, y, z), dtype=np.float32)


class SerialHaptic:
    """A haptic master on a serial port (HapticOutput, EmitsEvents, ReportsHealth).

    Args:
        port: the serial device, e.g. ``/dev/ttyACM0`` or the emulator's ``/dev/pts/N``.
        protocol: ``"hapticlab"`` (our framed protocol) or ``"inverse3"`` (Haply).
        baudrate: bits per second (ignored by native-USB boards and the Inverse3).
        rate_hz: the command rate the session runs the device at, Hz.
        device_max_force: the largest force ever written to the device, N; with
            the hapticlab protocol the smaller of this and the device's own maximum.
        open_timeout: how long the handshake may take, s (an Arduino Uno resets
            when the port opens and spends ~1.5 s in its bootloader).
        read_timeout: how long a reply may take before the device is lost, s
            (default 50 ms: long enough for a loaded host's stalls, shorter than the
            device watchdog's 100 ms).
        max_consecutive_errors: bad replies in a row tolerated; one more and the device is lost.
        watchdog: the device zeroes its force when no valid frame arrives for
            this long, s (hapticlab protocol; 0 turns it off).
        reconnect_interval: how often a lost device is tried again, s.
        wait_for_reply: True: each ``send`` waits for the device's answer to its
            force (the state is this command's reply; a loss shows in the tick it
            happens). False (hapticlab protocol only): ``send`` writes the force
            and takes whatever replies have already arrived, without waiting, so
            the loop never waits on the wire (USB full-speed boards answer a
            1 kHz command only a millisecond later); the state is then a tick or
            two old and a silent device is lost after ``read_timeout``.

    Attributes:
        info: one line naming the device, after ``open``.
        max_force: the force limit in use, N.
        written: how many forces were written.
        status: the device's status bits (``framing.STATUS_*``) in its last good reply.
    """

    def __init__(
        self,
        port: str = "",
        protocol: str = "hapticlab",
        baudrate: int = 1_000_000,
        rate_hz: float = 1000.0,
        device_max_force: float = 3.0,
        open_timeout: float = 3.0,
        read_timeout: float = 0.05,
        max_consecutive_errors: int = 5,
        watchdog: float = 0.1,
        reconnect_interval: float = 0.5,
        wait_for_reply: bool = True,
    ):
        if not isinstance(port, str) or not port.strip():
            raise ConfigError(
                "haptic.port: the serial device is required, e.g. --set haptic.port=/dev/ttyACM0 "
                "(hapticlab emulate master prints one)"
            )
        if protocol not in PROTOCOLS:
            raise ConfigError(f"haptic.protocol: must be one of {', '.join(map(repr, PROTOCOLS))}, got {protocol!r}")
        for key, value in (
            ("rate_hz", rate_hz),
            ("device_max_force", device_max_force),
            ("open_timeout", open_timeout),
            ("read_timeout", read_timeout),
            ("reconnect_interval", reconnect_interval),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"haptic.{key}: must be a finite number > 0, got {value!r}")
        if not baudrate > 0:
            raise ConfigError(f"haptic.baudrate: must be > 0, got {baudrate!r}")
        if not max_consecutive_errors >= 0:
            raise ConfigError(f"haptic.max_consecutive_errors: must be >= 0, got {max_consecutive_errors!r}")
        if not wait_for_reply and protocol != "hapticlab":
            raise ConfigError(
                'haptic.wait_for_reply: false needs protocol = "hapticlab" (the Inverse3\'s replies '
                "have no sequence numbers or framing to match them to their commands)"
            )
        if not (math.isfinite(watchdog) and 0 <= watchdog <= 65.535):
            raise ConfigError(f"haptic.watchdog: must be in [0, 65.535] s, got {watchdog!r}")
        self.port_name, self.protocol, self.baudrate = port.strip(), protocol, int(baudrate)
        self.rate_hz = rate_hz
        self.device_max_force = self.max_force = device_max_force
        self.open_timeout, self.read_timeout = open_timeout, read_timeout
        self.max_consecutive_errors, self.watchdog = int(max_consecutive_errors), watchdog
        self.reconnect_interval = reconnect_interval
        self.wait_for_reply = wait_for_reply
        self.port: SerialPort | None = None
        self.link: MasterLink | None = None
        self.pipeline: PipelinedLink | None = None  # the link, when sends do not wait for their reply
        self.info = ""
        self.written = 0
        self.errors_in_row = 0
        self.lost: MasterLostError | None = None  # why the device is lost (None while it answers)
        self.status = 0  # the device's status bits in its last good reply
        self.next_try = 0.0
        self.losses = 0
        self._state: DeviceState | None = None
        self._events: list[Event] = []
        self._reported: dict[str, int] = {}

    # ------------------------------------------------------------------ HapticOutput

    def open(self) -> None:
        """Open the port and do the protocol's handshake; MasterOpenError names the port and what went wrong."""
        self.port = SerialPort(self.port_name, self.baudrate, self.read_timeout)
        try:
            self.link = self._make_link(self.port)
            self.info = self.link.handshake(self.open_timeout)
        except MasterLostError as exc:  # the port died during the handshake
            self.port.close()
            raise MasterOpenError(f"haptic.port {self.port_name}: {exc}") from None
        except MasterOpenError:
            self.port.close()
            raise
        reported = self.link.max_force
        self.max_force = self.device_max_force if reported is None else min(self.device_max_force, reported)

    def send(self, command: HapticCommand) -> None:
        """Write the command's force (zero unless enabled; clamped; never NaN) and read the handle's state.

        Raises MasterLostError when the device is lost (see the module's docstring).
        """
        force_D = clamp_force(command.force_D, self.max_force) if command.enabled else ZERO3_F32
        if self.link is None:
            raise MasterLostError(f"{self.port_name}: not open", "gone")
        retrying = self.lost is not None
        if retrying:
            if time.monotonic() < self.next_try:
                raise self._still_lost("not tried again yet")
            self._retry()
            force_D = ZERO3_F32  # the first force after a loss is zero; the governor ramps up from there
        try:
            if self.pipeline is None or retrying:  # a retry waits for its answer: is the device back?
                outcomes = [self.link.exchange(force_D)]
            else:
                self.pipeline.post(force_D)
                outcomes = self.pipeline.poll()
        except MasterLostError as exc:
            self._lose(exc, command.t_ns)
            raise
        self.written += 1
        for reading in outcomes:
            self._take(reading, command.t_ns)
        self._report_counters(command.t_ns)
        if self.lost is not None:  # a retry that got a bad reply: still lost
            raise self._still_lost("a try got a bad reply")

    def _take(self, reading: Reading | None, t_ns: int) -> None:
        """One reply: a bad one counts towards the limit, a good one is the handle's new state."""
        if reading is None:
            self.errors_in_row += 1
            if self.errors_in_row > self.max_consecutive_errors:
                self._report_counters(t_ns)
                self._lose(
                    MasterLostError(f"{self.port_name}: {self.errors_in_row} bad replies in a row", "errors"), t_ns
                )
                raise self.lost
            return
        self.errors_in_row = 0
        if reading.status & framing.STATUS_FAULT:
            self._lose(
                MasterLostError(
                    f"{self.port_name}: the device reports a fault (status 0x{reading.status:02x})", "errors"
                ),
                t_ns,
            )
            raise self.lost
        self._state = DeviceState(t_ns, IDENTITY_QUAT, reading.p_DoHo_D, reading.buttons, reading.v_DHo_D)
        self.status = reading.status
        if reading.status:
            said = [text for bit, text in STATUS_TEXT.items() if reading.status & bit]
            self._events.append(
                Event(t_ns, "haptic_device_status", "haptic device: " + "; ".join(said), {"status": reading.status})
            )
        if self.lost is not None:
            self.lost = None
            self._events.append(
                Event(
                    t_ns, "haptic_device_back", f"haptic device answering again: {self.info}", {"port": self.port_name}
                )
            )

    servo_cf = send
    """CRTK name: servo in Cartesian force."""

    def state(self) -> DeviceState | None:
        """The handle's state from the last good reply (None before the first); orientation is identity (3-DOF)."""
        return self._state

    measured_cp = state
    """CRTK name: the measured Cartesian position (and velocity) of the handle."""

    def close(self) -> None:
        """Write zero force (best effort) and close the port."""
        if self.port is None:
            return
        if self.link is not None and self.lost is None:
            try:
                self.link.exchange(ZERO3_F32)
            except MasterLostError:
                pass
        self.port.close()
        self.port = self.link = self.pipeline = None

    # ------------------------------------------------------------------ capabilities

    def drain_events(self) -> list[Event]:
        """Losses, recoveries and link counter changes since the last call."""
        out, self._events = self._events, []
        return out

    def health_counters(self) -> dict[str, int]:
        """Link counts since ``open``: the protocol's (CRC errors, garbage bytes, NAKs, ...) and losses."""
        counters = dict(self.link.counters) if self.link is not None else {}
        counters["losses"] = self.losses
        counters["written"] = self.written
        return counters

    # ------------------------------------------------------------------ losing and finding the device

    def _lose(self, error: MasterLostError, t_ns: int) -> None:
        if self.lost is None:
            self.losses += 1
            self._events.append(
                Event(
                    t_ns,
                    "haptic_device_lost",
                    f"haptic device lost: {error}",
                    {"port": self.port_name, "cause": error.cause},
                )
            )
        self.lost = error
        self.errors_in_row = 0
        self.next_try = time.monotonic() + self.reconnect_interval
        if error.cause in ("silent", "errors"):  # it may still hear us: zero, at once, best effort
            try:
                self.link.post(ZERO3_F32)
            except MasterLostError:
                pass

    def _retry(self) -> None:
        """Ready a lost device for a try: reopen the port if it went away, redo the handshake if it restarted.

        The device stays lost until a good reply to the try comes back.
        """
        self.next_try = time.monotonic() + self.reconnect_interval
        try:
            if self.lost.cause == "gone":
                self.port.close()
                self.port = SerialPort(self.port_name, self.baudrate, self.read_timeout)
                self.link = self._make_link(self.port)
            if self.lost.cause in ("gone", "restarted"):
                self.info = self.link.handshake(min(self.open_timeout, self.reconnect_interval))
        except (MasterOpenError, MasterLostError) as exc:
            raise self._still_lost(f"trying again failed: {exc}") from None

    def _still_lost(self, why: str) -> MasterLostError:
        """The error a lost device's ``send`` raises: the loss's own message first (the session records
        one event per distinct message up to its first " ("), then why it is still lost."""
        return MasterLostError(f"{self.lost.args[0]} (still lost: {why})", "lost")

    def _make_link(self, port: SerialPort) -> MasterLink:
        if self.protocol == "hapticlab":
            link = HapticlabLink(port, self.read_timeout, self.watchdog)
            self.pipeline = None if self.wait_for_reply else link
            return link
        return Inverse3Link(port, self.read_timeout)

    def _report_counters(self, t_ns: int) -> None:
        event = link_event(t_ns, self.link.counters, self._reported)
        if event is not None:
            self._reported = dict(self.link.counters)
            self._events.append(event)


def link_event(t_ns: int, counters: dict[str, int], reported: dict[str, int]) -> Event | None:
    """A ``haptic_link`` event naming the link counters that changed since ``reported`` (None if none did)."""
    changed = {k: v for k, v in counters.items() if reported.get(k, 0) != v}
    if not changed:
        return None
    return Event(t_ns, "haptic_link", "haptic link: " + ", ".join(f"{k} {v}" for k, v in changed.items()), changed)


@hookimpl
def register_haptic_outputs(register):
    register("serial", SerialHaptic)
