"""The serial port under the ``serial`` plugin, and what each wire protocol's link does over it.

:class:`SerialPort` wraps pyserial (imported when a port is opened, never at import time) so that
every OS-level failure is a :class:`MasterLostError` naming the port. :class:`MasterLink` is what
the plugin needs of a protocol (``hapticlab_link.py``, ``inverse3_link.py``); each reply it reads
is a :class:`Reading`.
"""

from __future__ import annotations

import contextlib
import select
import time
import typing
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hapticlab.plugins.haptics.master import MasterLostError, MasterOpenError

if typing.TYPE_CHECKING:
    import serial as pyserial


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
        with contextlib.suppress(self._serial_exception, OSError):
            self.serial.close()


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
