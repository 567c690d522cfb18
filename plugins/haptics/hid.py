"""``hid``: a haptic master that speaks vendor-defined RawHID reports (hidapi), in a layout the lab describes.

Many DIY and small-lab masters (Teensy, Arduino Leonardo/Micro, STM32 and
RP2040 boards) enumerate as a vendor-defined HID device that exchanges fixed
64-byte reports: no driver to install, 1 ms interrupt transfers at full speed.
Every firmware lays its reports out differently, so the layout is config
(``hid_layout.py``: each field's byte offset, type and scale, and the preset
``teensy-rawhid``). The USB side is ``hid_transport.py``; ``hid_fake.py`` is a
simulated master for tests and dry runs (``transport = "fake"``).

Each ``send`` writes one OUT report (force, sequence number, flags) and waits
up to ``read_timeout`` for the IN report that echoes its sequence number
(position, velocity, buttons, status), which ``state()`` then returns. IN
reports with an older echo are stale (counted, skipped); reports with another
report id or of the wrong length are counted and skipped. A layout without an
``echo`` field takes the newest IN report that has arrived (staleness then
cannot be told).

What reaches the wire is never above ``device_max_force`` and never NaN: a
non-finite command is written as zero, a disabled one as zero with the enable
flag cleared, a larger one is scaled down along its direction
(``master.clamp_force``); each component is then quantised to its field's
type, saturating at the type's range (never wrapping around), and rounded
toward zero when rounding to the nearest count would take the norm above the
limit. A device maximum that a force field cannot represent is refused when the plugin is made.

A lost device raises MasterLostError from ``send``, so the session zeroes the
force and records an event: a read or write that fails (unplugged), or no IN
report answering the OUT report within ``read_timeout``. While lost, ``send``
raises at once, except every ``reconnect_interval`` when it reopens the device
if it went away and tries a zero force. Losses and recoveries are events
(``haptic_device_lost``, ``haptic_device_back``), as are changes of the link
counters (``haptic_link``) and of the device's status bits
(``haptic_device_status``).

CRTK names: ``servo_cf`` is ``send``, ``measured_cp`` is ``state``.
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import OptionError, choice, integer, number
from hapticlab.core.types import DeviceState, Event, HapticCommand
from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.hid_fake import FakeFault, FakeHidapi, FakeRawHidMaster
from hapticlab.plugins.haptics.hid_layout import POSITION_FIELDS, PRESETS, VELOCITY_FIELDS, RawHidLayout
from hapticlab.plugins.haptics.hid_transport import DeviceSelector, HidapiTransport, RawHidTransport
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError, clamp_force, link_event

IDENTITY_QUAT = np.array([1.0, 0.0, 0.0, 0.0])
ZERO3 = np.zeros(3)
STATUS_TEXT = {
    framing.STATUS_WATCHDOG: "its watchdog zeroed the force",
    framing.STATUS_CLAMPED: "it clamped a force to its own maximum",
    framing.STATUS_FAULT: "it reports a fault",
}


class HidHaptic:
    """A RawHID haptic master (HapticOutput, EmitsEvents, ReportsHealth).

    Args:
        vendor_id, product_id: USB ids of the device (default: the preset's).
        serial: its serial number, to choose among several identical devices.
        path: its platform path (``/dev/hidraw3``, or hidapi's ``1-2:1.0`` with the
            libusb backend this wheel uses on Linux); overrides the ids.
        usage_page, usage: the top-level collection to open when the device has
            several HID interfaces (default: the preset's).
        layout: a preset name (``"teensy-rawhid"``) or a table describing the
            reports (``hid_layout.py`` describes both).
        rate_hz: the command rate, Hz.
        device_max_force: the largest force ever written, N.
        read_timeout: how long the IN report answering a force may take before
            the device counts as lost, s.
        reconnect_interval: how often a lost device is tried again, s.
        transport: ``"hidapi"`` (a real device) or ``"fake"`` (a simulated master
            speaking the same layout, in this process: tests and dry runs).
        fake_faults: faults the fake plays, ``kind@report[:count]`` with kind
            ``unplug``, ``stale``, ``wrong_id`` or ``silent`` (transport ``"fake"``).

    Attributes:
        info: one line naming the device, after ``open``.
        fake: the simulated master when ``transport = "fake"``.
        written: OUT reports written.
    """

    def __init__(
        self,
        vendor_id: int | None = None,
        product_id: int | None = None,
        serial: str = "",
        path: str = "",
        usage_page: int | None = None,
        usage: int | None = None,
        layout: str | dict = "teensy-rawhid",
        rate_hz: float = 1000.0,
        device_max_force: float = 3.0,
        read_timeout: float = 0.05,
        reconnect_interval: float = 0.5,
        transport: str = "hidapi",
        fake_faults: list[str] | None = None,
    ):
        self.layout = RawHidLayout.from_config(layout)
        preset = PRESETS.get(layout, {}) if isinstance(layout, str) else {}
        for key, value in (
            ("rate_hz", rate_hz),
            ("device_max_force", device_max_force),
            ("read_timeout", read_timeout),
            ("reconnect_interval", reconnect_interval),
        ):
            number(key, value, above=0)
        vendor_id = preset.get("vendor_id") if vendor_id is None else vendor_id
        product_id = preset.get("product_id") if product_id is None else product_id
        if not path and (vendor_id is None or product_id is None):
            raise OptionError(
                "vendor_id" if vendor_id is None else "product_id",
                "must be given with a layout table (or haptic.path), e.g. --set haptic.vendor_id=0x16C0",
            )
        for key, ident in (
            ("vendor_id", vendor_id),
            ("product_id", product_id),
            ("usage_page", usage_page),
            ("usage", usage),
        ):
            if ident is not None:
                integer(key, ident, minimum=0, maximum=0xFFFF, hint=" (16 bits)")
        choice("transport", transport, ("hidapi", "fake"))
        try:
            faults = [FakeFault.parse(text) for text in fake_faults or []]
        except ValueError as exc:
            raise OptionError("fake_faults", str(exc)) from None
        if faults and transport != "fake":
            raise OptionError("fake_faults", f'must be empty unless transport = "fake", got {fake_faults!r}')
        if any(f.kind == "wrong_id" for f in faults) and self.layout.inp.report_id == 0:
            raise OptionError("fake_faults", "wrong_id needs numbered reports (layout.report_id > 0)")
        self.layout.check_reach(device_max_force)
        self.selector = DeviceSelector(
            vendor_id or 0,
            product_id or 0,
            serial,
            path,
            preset.get("usage_page") if usage_page is None else usage_page,
            preset.get("usage") if usage is None else usage,
        )
        self.rate_hz = rate_hz
        self.max_force = device_max_force
        self.read_timeout, self.reconnect_interval = read_timeout, reconnect_interval
        self.fake: FakeRawHidMaster | None = None
        if transport == "fake":
            self.fake = FakeRawHidMaster(
                self.layout,
                vendor_id or 0,
                product_id or 0,
                usage_page=self.selector.usage_page or 0,
                usage=self.selector.usage or 0,
                max_force=device_max_force,
                faults=faults,
            )
            if path:
                self.fake.path = path.encode()
            self.transport: RawHidTransport = HidapiTransport(FakeHidapi([self.fake]))
        else:
            self.transport = HidapiTransport()
        self._echo_mask = self.layout.echo_mask()
        self._in_read_size = self.layout.in_read_size()
        self.info = ""
        self.opened = False
        self.seq = 0
        self.written = 0
        self.lost: MasterLostError | None = None
        self.next_try = 0.0
        self.losses = 0
        self.status = 0
        self.counters = {"stale_reports": 0, "wrong_report_id": 0, "short_reports": 0, "bad_reports": 0}
        self._state: DeviceState | None = None
        self._events: list[Event] = []
        self._reported: dict[str, int] = {}

    # ------------------------------------------------------------------ HapticOutput

    def open(self) -> None:
        """Open the device (MasterOpenError names it and why not) and exchange a zero force with it."""
        self.info = self.transport.open(self.selector)
        self.opened = True
        try:
            reading = self._exchange(ZERO3, enabled=False)
        except MasterLostError as exc:
            self.transport.close()
            self.opened = False
            raise MasterOpenError(f"haptic: {self.info}: no answer to a first report: {exc}") from None
        self._take(reading, 0)

    def send(self, command: HapticCommand) -> None:
        """Write the command's force (zero unless enabled; clamped; never NaN) and read the handle's state.

        Raises MasterLostError when the device is lost (see the module's docstring).
        """
        enabled = bool(command.enabled)
        force_D = clamp_force(command.force_D, self.max_force) if enabled else ZERO3
        if not self.opened:
            raise MasterLostError(f"{self.selector.describe()}: not open", "gone")
        retrying = self.lost is not None
        if retrying:
            if time.monotonic() < self.next_try:
                raise self._still_lost("not tried again yet")
            self._retry()
            force_D, enabled = ZERO3, False  # the first force after a loss is zero; the governor ramps up
        try:
            reading = self._exchange(force_D, enabled)
        except MasterLostError as exc:
            if retrying:  # still lost: the loss keeps its first message (one event per loss)
                raise self._still_lost(f"a try failed: {exc}") from None
            self._lose(exc, command.t_ns)
            raise
        self._take(reading, command.t_ns)
        self._report_counters(command.t_ns)
        if self.lost is not None:
            raise self.lost

    servo_cf = send
    """CRTK name: servo in Cartesian force."""

    def state(self) -> DeviceState | None:
        """The handle's state from the last good IN report (None before); orientation is identity (3-DOF)."""
        return self._state

    measured_cp = state
    """CRTK name: the measured Cartesian position (and velocity) of the handle."""

    def close(self) -> None:
        """Write a zero force with the enable flag cleared (best effort) and close the device."""
        if not self.opened:
            return
        if self.lost is None:
            with contextlib.suppress(MasterLostError):
                self.transport.write(self._out_report(ZERO3, enabled=False))
        self.transport.close()
        self.opened = False

    # ------------------------------------------------------------------ capabilities

    def drain_events(self) -> list[Event]:
        """Losses, recoveries, link counter and device status changes since the last call."""
        out, self._events = self._events, []
        return out

    def health_counters(self) -> dict[str, int]:
        """Counts since ``open``: stale, wrong-id, short and bad IN reports, losses, OUT reports written."""
        return {**self.counters, "losses": self.losses, "written": self.written}

    # ------------------------------------------------------------------ one exchange

    def _out_report(self, force_D: np.ndarray, enabled: bool) -> bytes:
        return self.layout.out_report(force_D, self.max_force, self.seq, enabled)

    def _exchange(self, force_D: np.ndarray, enabled: bool) -> dict[str, float]:
        """Write one OUT report and return the decoded IN report answering it; MasterLostError if none comes."""
        self.seq += 1
        sent_seq = self.seq
        self.transport.write(self._out_report(force_D, enabled))
        self.written += 1
        deadline = time.monotonic() + self.read_timeout
        newest: dict[str, float] | None = None
        while True:
            remaining = deadline - time.monotonic()
            if newest is not None:  # no echo to match: drain what has come, keep the newest
                remaining = 0.0
            data = self.transport.read(self._in_read_size, max(remaining, 0.0))
            if data is None:
                if newest is not None:
                    return newest
                if remaining <= 0:
                    raise MasterLostError(
                        f"{self.selector.describe()}: no IN report answering the OUT report "
                        f"within {self.read_timeout * 1e3:g} ms",
                        "silent",
                    )
                continue
            values = self._decode(data)
            if values is None:
                continue
            if self._echo_mask is None:
                newest = values
            elif (values["echo"] - sent_seq) & self._echo_mask == 0:  # type: ignore[operator]  # echo is an integer field
                return values
            else:
                self.counters["stale_reports"] += 1

    def _decode(self, data: bytes) -> dict[str, float] | None:
        """An IN report's values, or None (counted) for one with another id, too short, or not finite."""
        inp = self.layout.inp
        if inp.report_id:
            if data[0] != inp.report_id:
                self.counters["wrong_report_id"] += 1
                return None
            data = data[1:]
        if len(data) < inp.size:
            self.counters["short_reports"] += 1
            return None
        values = inp.decode(data)
        if not all(math.isfinite(values[n]) for n in (*POSITION_FIELDS, *VELOCITY_FIELDS) if n in values):
            self.counters["bad_reports"] += 1
            return None
        return values

    def _take(self, values: dict[str, float], t_ns: int) -> None:
        status = int(values.get("status", 0))
        if status != self.status:
            said = [text for bit, text in STATUS_TEXT.items() if status & bit]
            self._events.append(
                Event(
                    t_ns,
                    "haptic_device_status",
                    "haptic device: " + ("; ".join(said) or "status clear"),
                    {"status": status},
                )
            )
            self.status = status
        if status & framing.STATUS_FAULT:
            self._lose(
                MasterLostError(
                    f"{self.selector.describe()}: the device reports a fault (status 0x{status:02x})", "errors"
                ),
                t_ns,
            )
            return
        p_DoHo_D = np.array([values[n] for n in POSITION_FIELDS])
        v_DHo_D = np.array([values[n] for n in VELOCITY_FIELDS]) if "velocity_x" in values else None
        self._state = DeviceState(t_ns, IDENTITY_QUAT, p_DoHo_D, int(values.get("buttons", 0)), v_DHo_D)
        if self.lost is not None:
            self.lost = None
            self._events.append(
                Event(
                    t_ns,
                    "haptic_device_back",
                    f"haptic device answering again: {self.info}",
                    {"device": self.selector.describe()},
                )
            )

    # ------------------------------------------------------------------ losing and finding the device

    def _lose(self, error: MasterLostError, t_ns: int) -> None:
        if self.lost is None:
            self.losses += 1
            self._events.append(
                Event(
                    t_ns,
                    "haptic_device_lost",
                    f"haptic device lost: {error}",
                    {"device": self.selector.describe(), "cause": error.cause},
                )
            )
        self.lost = error
        self.next_try = time.monotonic() + self.reconnect_interval
        if error.cause != "gone":  # it may still hear us: zero, at once, best effort
            with contextlib.suppress(MasterLostError):
                self.transport.write(self._out_report(ZERO3, enabled=False))

    def _retry(self) -> None:
        """Reopen a device that went away; it stays lost until an IN report answers the try."""
        self.next_try = time.monotonic() + self.reconnect_interval
        if self.lost.cause == "gone":  # type: ignore[union-attr]  # _retry runs while lost
            self.transport.close()
            try:
                self.info = self.transport.open(self.selector)
            except MasterOpenError as exc:
                raise self._still_lost(f"trying again failed: {exc}") from None

    def _still_lost(self, why: str) -> MasterLostError:
        """The loss's own message first (the session records one event per distinct message up to its first
        " ("), then why it is still lost."""
        return MasterLostError(f"{self.lost.args[0]} (still lost: {why})", "lost")  # type: ignore[union-attr]  # asked while lost

    def _report_counters(self, t_ns: int) -> None:
        event = link_event(t_ns, self.counters, self._reported)
        if event is not None:
            self._reported = dict(self.counters)
            self._events.append(event)


@hookimpl
def register_haptic_outputs(register):
    register("hid", HidHaptic)
