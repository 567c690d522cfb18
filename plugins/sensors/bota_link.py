"""The serial port under the ``bota`` sensor: raw at 460 800 baud, the set-up commands, reads that never block.

Every OS-level failure is a ``ConnectionError`` of one line naming the port and what failed.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import select
import termios
import time
import tty

from hapticlab.plugins.sensors import bota_protocol as bp


class BotaLink:
    """An open port to a Bota serial sensor (exclusive: ``flock``, as pyserial's ``exclusive=True``).

    Args:
        port: the serial device.
        timeout: how long each set-up step may take, s.
    """

    def __init__(self, port: str, timeout: float):
        self.port, self.timeout = port, timeout
        try:
            fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError as exc:
            raise ConnectionError(f"Bota sensor {port}: cannot open: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            tty.setraw(fd)
            attrs = termios.tcgetattr(fd)
            attrs[4] = attrs[5] = termios.B460800
            attrs[2] &= ~(termios.PARENB | termios.CSTOPB | termios.CRTSCTS)  # 8N1, no flow control
            attrs[2] |= termios.CLOCAL | termios.CREAD
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
            termios.tcflush(fd, termios.TCIFLUSH)  # what came before we asked is stale
        except OSError as exc:
            os.close(fd)
            held = " (held by another program)" if isinstance(exc, BlockingIOError) else ""
            raise ConnectionError(f"Bota sensor {port}: cannot use the port{held}: {exc.strerror or exc}") from None
        self.fd = fd

    def set_up(self, temperature_compensation: bool, sinc_length: int) -> bytes:
        """Configuration mode, binary frames with the calibration on, the sinc length, run: the bytes after the
        run command's answer (the first frames)."""
        self.command(b"C", "C", repeat=True)  # the stream stops; a sensor still booting answers later
        self.command(bp.communication_command(temperature_compensation), "c")
        self.command(bp.filter_command(sinc_length), "f")
        return self.command(b"R", "R")

    def command(self, command: bytes, letter: str, repeat: bool = False) -> bytes:
        """Send a command and wait for its answer ``r,E,letter,0``; the bytes after the answer. ``repeat``:
        send it again every 0.25 s while there is no answer (the sensor may still be booting)."""
        answer = re.compile(rb"r,(\d+)," + letter.encode() + rb",0")
        received = bytearray()
        deadline = time.monotonic() + self.timeout
        sent = 0.0
        while True:
            now = time.monotonic()
            if sent == 0.0 or (repeat and now - sent > 0.25):
                self.write(command)
                sent = now
            if now > deadline:
                what = "no bytes at all" if not received else f"{len(received)} bytes but no answer"
                raise ConnectionError(
                    f"Bota sensor {self.port}: no answer to {command.decode()!r} within {self.timeout:g} s "
                    f"({what}: is it a Bota serial sensor, powered, at 460800 baud?)"
                )
            select.select([self.fd], [], [], 0.01)
            received += self.read()
            found = answer.search(received)
            if found is not None:
                if found.group(1) != b"0":
                    said = found.group(0).decode(errors="replace")
                    raise ConnectionError(f"Bota sensor {self.port}: refused {command.decode()!r} ({said})")
                return bytes(received[found.end() :])

    def write(self, data: bytes) -> None:
        try:
            os.write(self.fd, data)
        except OSError as exc:
            why = exc.strerror or exc
            raise ConnectionError(f"Bota sensor {self.port}: write failed: {why} (unplugged?)") from None

    def read(self) -> bytes:
        """Every byte waiting, without blocking; ConnectionError (one line) when the port is gone."""
        chunks = []
        while True:
            try:
                data = os.read(self.fd, 65536)
            except BlockingIOError:
                break
            except OSError as exc:
                raise ConnectionError(
                    f"Bota sensor {self.port}: the port failed ({exc.strerror or exc}): unplugged? no sensor data"
                ) from None
            if not data:
                raise ConnectionError(f"Bota sensor {self.port}: the port hung up (unplugged?): no sensor data")
            chunks.append(data)
        return b"".join(chunks)

    def wait(self, timeout: float) -> None:
        """Until a byte is waiting or ``timeout`` s have passed."""
        select.select([self.fd], [], [], timeout)

    def close(self, stop: bool = True) -> None:
        """``C`` (the stream stops: configuration mode) when ``stop``, then let the port go."""
        if self.fd < 0:
            return
        if stop:
            with contextlib.suppress(OSError):
                os.write(self.fd, b"C")
        with contextlib.suppress(OSError):
            os.close(self.fd)
        self.fd = -1
