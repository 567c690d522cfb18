"""The small transport under the ``hid`` haptic plugin: RawHID reports to and from one device.

:class:`RawHidTransport` is what the plugin needs of a link: open a device
chosen by ids (or a path), write one OUT report, read one IN report within a
timeout, close. :class:`HidapiTransport` implements it on a hidapi-like module
(:class:`HidapiModule`): the real ``hid`` module of the PyPI package
``hidapi`` (imported when the transport is opened, never at import time), or
``hid_fake.FakeHidapi``, a stand-in with the same API for tests and dry runs.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Any, Protocol

from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError


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
            with contextlib.suppress(OSError, ValueError):
                self.device.close()
            self.device = None

    def _error(self) -> str:
        try:
            return self.device.error() or "unknown error"  # type: ignore[union-attr]  # asked while open
        except (OSError, ValueError):
            return "unknown error"


def _describe_info(info: dict[str, Any]) -> str:
    path = info.get("path", b"")
    return (
        f"{info.get('vendor_id', 0):04x}:{info.get('product_id', 0):04x} "
        f"usage page 0x{info.get('usage_page', 0):04x} usage 0x{info.get('usage', 0):04x} "
        f"serial {info.get('serial_number', '')!r} at {path.decode(errors='replace')}"
    )
