"""``serial``: a haptic master on a serial port (USB CDC, UART), in one of two wire protocols.

``protocol = "hapticlab"``: our framed binary protocol for DIY and Arduino
masters (host side ``hapticlab_link.py``, bytes ``framing.py``, specified in
``docs/serial-protocol.md``, device side in ``firmware/hapticlab_master/``).
``protocol = "inverse3"``: the Haply Inverse3's own serial protocol (host side
``inverse3_link.py``, bytes ``inverse3.py``). The port itself is ``serial_port.py``.

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

import contextlib
import time

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import OptionError, boolean, choice, integer, number
from hapticlab.core.types import DeviceState, Event, HapticCommand
from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.hapticlab_link import HapticlabLink
from hapticlab.plugins.haptics.inverse3_link import Inverse3Link
from hapticlab.plugins.haptics.master import ZERO3_F32, MasterLostError, MasterOpenError, clamp_force, link_event
from hapticlab.plugins.haptics.serial_port import MasterLink, PipelinedLink, Reading, SerialPort

PROTOCOLS = ("hapticlab", "inverse3")
IDENTITY_QUAT = np.array([1.0, 0.0, 0.0, 0.0])
STATUS_TEXT = {
    framing.STATUS_WATCHDOG: "its watchdog zeroed the force (no host frame in time)",
    framing.STATUS_CLAMPED: "it clamped a force to its own maximum",
}


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
            raise OptionError(
                "port",
                "must name the serial device, e.g. --set haptic.port=/dev/ttyACM0 "
                f"(hapticlab emulate master prints one), got {port!r}",
            )
        choice("protocol", protocol, PROTOCOLS)
        for key, value in (
            ("rate_hz", rate_hz),
            ("device_max_force", device_max_force),
            ("open_timeout", open_timeout),
            ("read_timeout", read_timeout),
            ("reconnect_interval", reconnect_interval),
        ):
            number(key, value, above=0)
        integer("baudrate", baudrate, minimum=1, hint=" (bit/s)")
        integer("max_consecutive_errors", max_consecutive_errors, minimum=0)
        if not boolean("wait_for_reply", wait_for_reply) and protocol != "hapticlab":
            raise OptionError(
                "wait_for_reply",
                'false needs protocol = "hapticlab" (the Inverse3\'s replies have no sequence numbers or '
                "framing to match them to their commands)",
            )
        number("watchdog", watchdog, minimum=0, maximum=65.535, hint=" s (0: off)")
        self.port_name, self.protocol, self.baudrate = port.strip(), protocol, baudrate
        self.rate_hz = rate_hz
        self.device_max_force = self.max_force = device_max_force
        self.open_timeout, self.read_timeout = open_timeout, read_timeout
        self.max_consecutive_errors, self.watchdog = max_consecutive_errors, watchdog
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
                raise self.lost  # type: ignore[misc]  # _lose has just set it
            return
        self.errors_in_row = 0
        if reading.status & framing.STATUS_FAULT:
            self._lose(
                MasterLostError(
                    f"{self.port_name}: the device reports a fault (status 0x{reading.status:02x})", "errors"
                ),
                t_ns,
            )
            raise self.lost  # type: ignore[misc]  # _lose has just set it
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
            with contextlib.suppress(MasterLostError):
                self.link.exchange(ZERO3_F32)
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
            with contextlib.suppress(MasterLostError):
                self.link.post(ZERO3_F32)  # type: ignore[union-attr]  # lost while open

    def _retry(self) -> None:
        """Ready a lost device for a try: reopen the port if it went away, redo the handshake if it restarted.

        The device stays lost until a good reply to the try comes back.
        """
        self.next_try = time.monotonic() + self.reconnect_interval
        try:
            if self.lost.cause == "gone":  # type: ignore[union-attr]  # _retry runs while lost
                self.port.close()  # type: ignore[union-attr]  # open
                self.port = SerialPort(self.port_name, self.baudrate, self.read_timeout)
                self.link = self._make_link(self.port)
            if self.lost.cause in ("gone", "restarted"):  # type: ignore[union-attr]  # _retry runs while lost
                self.info = self.link.handshake(min(self.open_timeout, self.reconnect_interval))  # type: ignore[union-attr]  # open
        except (MasterOpenError, MasterLostError) as exc:
            raise self._still_lost(f"trying again failed: {exc}") from None

    def _still_lost(self, why: str) -> MasterLostError:
        """The error a lost device's ``send`` raises: the loss's own message first (the session records
        one event per distinct message up to its first " ("), then why it is still lost."""
        return MasterLostError(f"{self.lost.args[0]} (still lost: {why})", "lost")  # type: ignore[union-attr]  # asked while lost

    def _make_link(self, port: SerialPort) -> MasterLink:
        if self.protocol == "hapticlab":
            link = HapticlabLink(port, self.read_timeout, self.watchdog)
            self.pipeline = None if self.wait_for_reply else link
            return link
        return Inverse3Link(port, self.read_timeout)

    def _report_counters(self, t_ns: int) -> None:
        event = link_event(t_ns, self.link.counters, self._reported)  # type: ignore[union-attr]  # send() checked it is open
        if event is not None:
            self._reported = dict(self.link.counters)  # type: ignore[union-attr]  # send() checked it is open
            self._events.append(event)


@hookimpl
def register_haptic_outputs(register):
    register("serial", SerialHaptic)
