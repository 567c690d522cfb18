"""A simulated RawHID haptic master behind a hidapi-like module: the ``hid`` plugin's ``transport = "fake"``.

No virtual HID device can be made on a kernel without uhid, so tests and dry
runs use this fake. :class:`FakeRawHidMaster` is a device model, not a
recorder: it decodes each OUT report with the session's layout, renders the
force on a simulated handle (a mass on a centring spring, integrated one step
per OUT report), answers with an IN report encoded with the same layout, and
can be made to fail the ways a real one does: unplugged (hidapi's ``read``
raises ``OSError("read error")``, ``write`` returns -1, ``open`` raises
``OSError("open failed")``), stale replies (the previous report again),
replies with another report id, silence. :class:`FakeHidapi` puts fake masters
on a bus with hidapi's module API: ``HidapiTransport(FakeHidapi([master]))``.

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
from typing import Any

import numpy as np

from hapticlab.plugins.haptics.framing import STATUS_CLAMPED
from hapticlab.plugins.haptics.hid_layout import RawHidLayout

IN_QUEUE_REPORTS = 30
"""Reports hidapi's libusb backend keeps before it drops the oldest (the fake keeps as many)."""


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
    def parse(cls, text: str) -> FakeFault:
        """``kind@report[:count]``, e.g. ``unplug@2600`` or ``stale@10:3``; ValueError naming what is wrong."""
        kind, _, rest = text.partition("@")
        at, _, count = rest.partition(":")
        if kind not in cls.KINDS or not at.isdigit() or (count and not count.isdigit()):
            raise ValueError(f"must be kind@report[:count] with kind one of {', '.join(cls.KINDS)}, got {text!r}")
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

    layout: RawHidLayout
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

    def __post_init__(self) -> None:
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
        if "flags" in values and not values["flags"] & 1:  # type: ignore[operator]  # flags is an integer field
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

    def __init__(self, bus: FakeHidapi):
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
