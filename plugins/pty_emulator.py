"""What the emulated serial devices share: a raw pseudo-terminal pair served by a thread.

The slave side is the device's port (``port``: a real serial port's stand-in, which pyserial, minimalmodbus
and the vendors' clients open as they would the device); the emulator reads and writes the master side in
``_serve``, a daemon thread, until :meth:`PtyEmulator.stop`. Used by the master-device, Robotiq FT 300 and
Bota emulators.
"""

from __future__ import annotations

import contextlib
import os
import threading
import tty
from typing import Self


class PtyEmulator:
    """A device on a pseudo-terminal (a context manager: started on entry, stopped on exit).

    A subclass sets ``port = ""``, ``_master_fd = _slave_fd = -1``, ``_thread = None`` and
    ``_stop = threading.Event()`` in its ``__init__``, defines ``_serve``, names its thread (``THREAD``), says
    whether a write may block (``NONBLOCKING``) and does what powering on does in ``_powered_on``.
    """

    THREAD = "emulator"
    """The serving thread's name, before the port."""
    NONBLOCKING = False
    """The master side non-blocking: a write to a full pty then fails (the bytes are dropped) where it would
    wait for the client to read."""

    port: str
    _master_fd: int
    _slave_fd: int
    _thread: threading.Thread | None
    _stop: threading.Event

    def start(self) -> Self:
        """Open the pty pair (raw), power on and serve in a daemon thread; ``port`` then names the slave side."""
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)  # no echo, no line editing, no CR/LF translation: bytes as sent
        if self.NONBLOCKING:
            os.set_blocking(self._master_fd, False)
        self.port = os.ttyname(self._slave_fd)
        self._powered_on()
        self._thread = threading.Thread(target=self._serve, name=f"{self.THREAD} {self.port}", daemon=True)
        self._thread.start()
        return self

    def _powered_on(self) -> None:
        """What the device does when it powers on, before it serves (nothing here)."""

    def _serve(self) -> None:
        raise NotImplementedError

    def stop(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        self._close_fds()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _close_fds(self) -> None:
        for fd in (self._master_fd, self._slave_fd):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master_fd = self._slave_fd = -1
