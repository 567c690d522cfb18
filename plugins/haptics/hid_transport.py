"""The small transport under the ``hid`` haptic plugin: RawHID reports to and from one device.

:class:`RawHidTransport` is what the plugin needs of a link: open a device
chosen by ids (or a path), write one OUT report, read one IN report within a
timeout, close. :class:`HidapiTransport` implements it on a hidapi-like module
(:class:`HidapiModule`): the real ``hid`` module of the PyPI package
``hidapi`` (imported when the transport is opened, never at import time), or
:class:`FakeHidapi`, a stand-in with the same API for tests and dry runs (this
machine's kernel has no uhid, so no virtual HID device can be made).

:class:`FakeRawHidMaster` is a device model, not a recorder: it decodes each
OUT report with the session's layout, renders the force on a simulated handle
(a mass on a centring spring, integrated one step per OUT report), answers
with an IN report encoded with the same layout, and can be made to fail the
ways a real one does: unplugged (hidapi's ``read`` raises ``OSError("read
error")``, ``write`` returns -1, ``open`` raises ``OSError("open failed")``),
stale replies (the previous report again), replies with another report id,
silence.

hidapi's conventions, which the fake keeps: ``write`` takes the report id
first (0 for a device without numbered reports, then not sent on the bus) and
returns the bytes written or -1; ``read`` returns a list of ints, with the
report id first only for numbered reports, or [] when nothing came in time;
with ``set_nonblocking(1)`` a ``read`` without a timeout returns at once.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from hapticlab.plugins.haptics.framing import STATUS_CLAMPED
from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError

if TYPE_CHECKING:
    from hapticlab.plugins.haptics.hid import RawHidLayout

IN_QUEUE_REPORTS = 30
"""Reports hidapi's libusb backend keeps before it drops the oldest (the fake keeps as many)."""


@dataclass(frozen=True, slots=True)
class DeviceSelector:
    """Which HID device to open.

    Attributes:
        vendor_id, product_id: the USB ids (0 matches any).
        serial: the device's serial number string ("" matches any).
        path: the platform path (``/dev/hidraw3`` or hidapi's ``1-2:1.0``); when
            set, the ids are not used.
        usage_page, usage: the top-level collection, for devices that show up as
            several HID interfaces under the same ids (a Teensy in RawHID mode also
            has a serial-emulation interface, usage page 0xFFC9); None matches any.
    """

    vendor_id: int = 0
    product_id: int = 0
    serial: str = ""
    path: str = ""
    usage_page: int | None = None
    usage: int | None = None

    def describe(self) -> str:
        if self.path:
            return f"HID device {self.path}"
        text = f"HID device {self.vendor_id:04x}:{self.product_id:04x}"
        if self.serial:
            text += f" serial {self.serial!r}"
        if self.usage_page is not None:
            text += f" usage page 0x{self.usage_page:04x}"
        if self.usage is not None:
            text += f" usage 0x{self.usage:04x}"
        return text

    def matches(self, info: dict[str, Any]) -> bool:
        """Whether one of hidapi's ``enumerate`` entries is this device."""
        return (
            (not self.serial or info.get("serial_number") == self.serial)
            and (self.usage_page is None or info.get("usage_page") == self.usage_page)
            and (self.usage is None or info.get("usage") == self.usage)
        )


class RawHidTransport(Protocol):
    """One RawHID device, report by report.

    ``open(selector)`` opens it and returns one line naming it (MasterOpenError
    naming the device and why not). ``write(report)`` sends one OUT report,
    report id first (0: unnumbered). ``read(size, timeout_s)`` returns one IN
    report (report id first only for numbered reports; at most ``size`` bytes),
    waiting up to ``timeout_s`` s (0: only what has already arrived), or None.
    Both raise MasterLostError (cause ``"gone"``) when the device fails.
    """

    def open(self, selector: DeviceSelector) -> str: ...
    def write(self, report: bytes) -> None: ...
    def read(self, size: int, timeout_s: float) -> bytes | None: ...
    def close(self) -> None: ...


class HidapiDevice(Protocol):
    """The part of hidapi's ``hid.device`` the transport uses."""

    def open_path(self, path: bytes) -> None: ...
    def set_nonblocking(self, v: int) -> int: ...
    def write(self, buff: Any) -> int: ...
    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]: ...
    def error(self) -> str: ...
    def get_product_string(self) -> str: ...
    def get_manufacturer_string(self) -> str: ...
    def close(self) -> None: ...


class HidapiModule(Protocol):
    """The part of hidapi's ``hid`` module the transport uses: ``device()`` and ``enumerate``."""

    def device(self) -> HidapiDevice: ...
    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict[str, Any]]: ...


def _import_hidapi() -> HidapiModule:
    try:
        import hid
    except ImportError:
        raise MasterOpenError(
            "haptic: the hid plugin needs the hidapi package (pip install 'hidapi>=0.14,<0.15'; "
            "not the package named 'hid', which has the same module name)"
        ) from None
    if not hasattr(hid, "device"):
        raise MasterOpenError(
            f"haptic: the module 'hid' at {getattr(hid, '__file__', '?')} is not hidapi's "
            "(the package 'hid' is installed: pip uninstall hid; pip install hidapi)"
        )
    return hid


class HidapiTransport:
    """RawHidTransport on hidapi (or on anything with its API, such as :class:`FakeHidapi`).

    Args:
        module: the hidapi-like module; None imports hidapi's ``hid`` when opened.
    """

    def __init__(self, module: HidapiModule | None = None):
        self.module = module
        self.device: HidapiDevice | None = None
        self.name = ""

    def open(self, selector: DeviceSelector) -> str:
        if self.module is None:
            self.module = _import_hidapi()
        self.name = selector.describe()
        if selector.path:
            path, info = selector.path.encode(), {}
        else:
            listed = self.module.enumerate(selector.vendor_id, selector.product_id)
            found = [info for info in listed if selector.matches(info)]
            if not found:
                others = "; ".join(_describe_info(info) for info in listed)
                raise MasterOpenError(
                    f"haptic: no {self.name}"
                    + (
                        f" (there is {others})"
                        if others
                        else " (plugged in? on Linux, does a udev rule give you access to it?)"
                    )
                )
            if len(found) > 1:
                raise MasterOpenError(
                    f"haptic: {len(found)} devices match {self.name}: "
                    + "; ".join(_describe_info(info) for info in found)
                    + " (set haptic.serial, haptic.usage_page or haptic.path)"
                )
            info = found[0]
            path = info["path"]
        device = self.module.device()
        try:
            device.open_path(path)
        except (OSError, ValueError) as exc:
            raise MasterOpenError(
                f"haptic: cannot open {self.name} at {path.decode(errors='replace')}: {exc} "
                "(held by another program? permission: a udev rule for the device?)"
            ) from None
        device.set_nonblocking(1)  # read() without a timeout returns at once
        self.device = device
        try:
            product = device.get_product_string() or info.get("product_string", "")
            maker = device.get_manufacturer_string() or info.get("manufacturer_string", "")
        except (OSError, ValueError):
            product, maker = info.get("product_string", ""), info.get("manufacturer_string", "")
        return f"{maker} {product}".strip() + f" ({self.name}, path {path.decode(errors='replace')})"

    def write(self, report: bytes) -> None:
        if self.device is None:
            raise MasterLostError(f"{self.name}: not open", "gone")
        try:
            written = self.device.write(report)
        except (OSError, ValueError) as exc:
            raise MasterLostError(f"{self.name}: write failed: {exc}", "gone") from None
        if written < 0:
            raise MasterLostError(f"{self.name}: write failed: {self._error()}", "gone")

    def read(self, size: int, timeout_s: float) -> bytes | None:
        if self.device is None:
            raise MasterLostError(f"{self.name}: not open", "gone")
        timeout_ms = max(0, math.ceil(timeout_s * 1e3))  # 0: hid_read, which the nonblocking flag makes return at once
        try:
            data = self.device.read(size, timeout_ms)
        except (OSError, ValueError) as exc:
            raise MasterLostError(f"{self.name}: read failed: {exc}", "gone") from None
        return bytes(data) if data else None

    def close(self) -> None:
        if self.device is not None:
            try:
                self.device.close()
            except (OSError, ValueError):
                pass
            self.device = None

    def _error(self) -> str:
        try:
            return self.device.error() or "unknown error"
        except (OSError, ValueError):
            return "unknown error"


def _describe_info(info: dict[str, Any]) -> str:
    path = info.get("path", b"")
    return (
        f"{info.get('vendor_id', 0):04x}:{info.get('product_id', 0):04x} "
        f"usage page 0x{info.get('usage_page', 0):04x} usage 0x{info.get('usage', 0):04x} "
        f"serial {info.get('serial_number', '')!r} at {path.decode(errors='replace')}"
    )


# --------------------------------------------------------------------------- the fake device


@dataclass
class FakeFault:
    """A fault the fake master plays when its ``at_report``-th OUT report arrives (1 = the first).

    ``kind`` is ``"unplug"``, ``"stale"`` (the next ``count`` replies repeat
    the previous IN report), ``"wrong_id"`` (the next ``count`` replies carry
    another report id; numbered layouts only) or ``"silent"`` (no reply to the
    next ``count`` OUT reports).
    """

    kind: str
    at_report: int
    count: int = 1

    KINDS = ("unplug", "stale", "wrong_id", "silent")

    @classmethod
    def parse(cls, text: str) -> "FakeFault":
        """``kind@report[:count]``, e.g. ``unplug@2600`` or ``stale@10:3``; ValueError naming what is wrong."""
        kind, _, rest = text.partition("@")
        at, _, count = rest.partition(":")
        if kind not in cls.KINDS or not at.isdigit() or (count and not count.isdigit()):
            raise ValueError(f"{text!r}: expected kind@report[:count] with kind one of {', '.join(cls.KINDS)}")
        return cls(kind, int(at), int(count) if count else 1)


@dataclass
class FakeRawHidMaster:
    """A simulated RawHID haptic master that speaks the session's report layout.

    Each OUT report is decoded with ``layout.out``; the force (zero unless the
    enable flag is set, when the layout has flags) is clamped to ``max_force``
    and pushes the handle: a mass ``mass_kg`` on a spring ``stiffness_n_per_m``
    to the centre with damping ``damping_n_s_per_m``, advanced ``dt_s`` per
    OUT report (semi-implicit Euler). The answer is one IN report with the
    handle's position, velocity, ``buttons``, the echoed sequence number and
    the status bits (``STATUS_CLAMPED`` when it clamped).

    Attributes:
        forces: each force received, decoded as the device reads it, N.
        applied_force_D: (3,) the force it renders now, N.
        p_DoHo_D, v_DHo_D: (3,) the handle's position (m) and velocity (m/s).
        plugged: False once unplugged.
        counts: reports received and sent, faults played.
    """

    layout: "RawHidLayout"
    vendor_id: int = 0x16C0
    product_id: int = 0x0486
    serial: str = "fake-0001"
    usage_page: int = 0xFFAB
    usage: int = 0x0200
    path: bytes = b"fake:rawhid-0"
    max_force: float = 3.0
    mass_kg: float = 0.05
    stiffness_n_per_m: float = 200.0
    damping_n_s_per_m: float = 2.0
    dt_s: float = 1e-3
    buttons: int = 0
    faults: list[FakeFault] = field(default_factory=list)
    forces: list[np.ndarray] = field(default_factory=list)
    plugged: bool = True

    def __post_init__(self):
        self.p_DoHo_D = np.zeros(3)
        self.v_DHo_D = np.zeros(3)
        self.applied_force_D = np.zeros(3)
        self.inbox: deque[bytes] = deque(maxlen=IN_QUEUE_REPORTS)
        self.last_reply: bytes | None = None
        self.counts = {"out_reports": 0, "in_reports": 0, "clamped": 0, "bad_out_reports": 0}
        self._stale = self._wrong_id = self._silent = 0

    # faults, callable from a test at any time
    def unplug(self) -> None:
        """The cable is pulled: reads raise, writes fail, opening fails."""
        self.plugged = False
        self.inbox.clear()

    def replug(self) -> None:
        self.plugged = True

    def send_stale(self, count: int = 1) -> None:
        """The next ``count`` replies repeat the previous IN report."""
        self._stale += count

    def send_wrong_id(self, count: int = 1) -> None:
        """The next ``count`` replies carry another report id."""
        if self.layout.inp.report_id == 0:
            raise ValueError("wrong_id: the layout's reports are not numbered")
        self._wrong_id += count

    def go_silent(self, count: int = 1) -> None:
        """No reply to the next ``count`` OUT reports."""
        self._silent += count

    # the bus side
    def receive(self, report: bytes) -> None:
        """One OUT report, report id first as hidapi's ``write`` takes it."""
        out = self.layout.out
        data = report[1:] if report[:1] == b"\x00" and out.report_id == 0 else report
        if out.report_id:
            if data[:1] != bytes([out.report_id]):
                self.counts["bad_out_reports"] += 1
                return
            data = data[1:]
        if len(data) < out.size:
            self.counts["bad_out_reports"] += 1
            return
        self.counts["out_reports"] += 1
        for fault in self.faults:
            if fault.at_report == self.counts["out_reports"]:
                self._play(fault)
        if not self.plugged:
            return
        values = out.decode(data)
        force_D = np.array([values["force_x"], values["force_y"], values["force_z"]], dtype=float)
        if "flags" in values and not values["flags"] & 1:
            force_D = np.zeros(3)
        self.forces.append(force_D)
        status = 0
        norm = float(np.linalg.norm(force_D)) if np.isfinite(force_D).all() else math.inf
        if not math.isfinite(norm):
            force_D = np.zeros(3)
        elif norm > self.max_force:
            force_D = force_D * (self.max_force / norm)
            status |= STATUS_CLAMPED
            self.counts["clamped"] += 1
        self.applied_force_D = force_D
        a = (force_D - self.stiffness_n_per_m * self.p_DoHo_D - self.damping_n_s_per_m * self.v_DHo_D) / self.mass_kg
        self.v_DHo_D = self.v_DHo_D + a * self.dt_s
        self.p_DoHo_D = self.p_DoHo_D + self.v_DHo_D * self.dt_s
        if self._silent:
            self._silent -= 1
            return
        if self._stale and self.last_reply is not None:
            self._stale -= 1
            self._queue(self.last_reply)
            return
        reply = self.layout.inp.encode(
            {
                "position_x": self.p_DoHo_D[0],
                "position_y": self.p_DoHo_D[1],
                "position_z": self.p_DoHo_D[2],
                "velocity_x": self.v_DHo_D[0],
                "velocity_y": self.v_DHo_D[1],
                "velocity_z": self.v_DHo_D[2],
                "buttons": self.buttons,
                "echo": values.get("seq", 0),
                "status": status,
            }
        )
        if self.layout.inp.report_id:
            reply = bytes([self.layout.inp.report_id]) + reply
        self.last_reply = reply
        if self._wrong_id:
            self._wrong_id -= 1
            reply = bytes([(self.layout.inp.report_id % 255) + 1]) + reply[1:]
        self._queue(reply)

    def _queue(self, reply: bytes) -> None:
        self.inbox.append(reply)
        self.counts["in_reports"] += 1

    def _play(self, fault: FakeFault) -> None:
        if fault.kind == "unplug":
            self.unplug()
        elif fault.kind == "stale":
            self.send_stale(fault.count)
        elif fault.kind == "wrong_id":
            self.send_wrong_id(fault.count)
        else:
            self.go_silent(fault.count)

    def enumerate_info(self) -> dict[str, Any]:
        """This device as hidapi's ``enumerate`` lists it."""
        return {
            "path": self.path,
            "vendor_id": self.vendor_id,
            "product_id": self.product_id,
            "serial_number": self.serial,
            "release_number": 0x0100,
            "manufacturer_string": "hapticlab",
            "product_string": "fake RawHID master",
            "usage_page": self.usage_page,
            "usage": self.usage,
            "interface_number": 0,
        }


class FakeHidDevice:
    """hidapi's ``hid.device`` API over the :class:`FakeRawHidMaster` s of a :class:`FakeHidapi`."""

    def __init__(self, bus: "FakeHidapi"):
        self.bus = bus
        self.master: FakeRawHidMaster | None = None
        self.nonblocking = False

    def open_path(self, path: bytes) -> None:
        for master in self.bus.masters:
            if master.path == path and master.plugged:
                self.master = master
                return
        raise OSError("open failed")

    def set_nonblocking(self, v: int) -> int:
        self._opened()
        self.nonblocking = bool(v)
        return 0

    def write(self, buff: Any) -> int:
        master = self._opened()
        data = bytes(buff)
        if not master.plugged:
            return -1
        master.receive(data)
        return len(data)

    def read(self, max_length: int, timeout_ms: int = 0) -> list[int]:
        master = self._opened()
        if not master.plugged:
            raise OSError("read error")
        if master.inbox:
            return list(master.inbox.popleft()[:max_length])
        if timeout_ms <= 0 and not self.nonblocking:
            raise RuntimeError("FakeHidDevice.read: a blocking read with nothing queued would wait forever")
        return []  # the replies are made on write: nothing more comes while waiting

    def error(self) -> str:
        master = self._opened()
        return "" if master.plugged else "libusb: LIBUSB_ERROR_NO_DEVICE"

    def get_product_string(self) -> str:
        return self._opened().enumerate_info()["product_string"]

    def get_manufacturer_string(self) -> str:
        return self._opened().enumerate_info()["manufacturer_string"]

    def close(self) -> None:
        self.master = None

    def _opened(self) -> FakeRawHidMaster:
        if self.master is None:
            raise ValueError("not open")
        return self.master


class FakeHidapi:
    """A hidapi-like module whose bus holds fake masters: ``HidapiTransport(FakeHidapi([master]))``."""

    def __init__(self, masters: list[FakeRawHidMaster]):
        self.masters = masters

    def device(self) -> FakeHidDevice:
        return FakeHidDevice(self)

    def enumerate(self, vendor_id: int = 0, product_id: int = 0) -> list[dict[str, Any]]:
        return [
            m.enumerate_info()
            for m in self.masters
            if m.plugged and vendor_id in (0, m.vendor_id) and product_id in (0, m.product_id)
        ]
