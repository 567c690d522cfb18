"""The master emulator: a serial haptic master on a pseudo-terminal, in either wire protocol.

The emulator opens a pty pair (raw mode) and plays the device on its master
side; the slave side (``/dev/pts/N``, printed first) is the port a session or
a vendor client opens as if it were the device's USB serial port. The handle
moves along a scripted path in the device frame D (a slow circle or
figure-eight, a hold, or a press down and back) or a recorded one (a CSV of
``t, x, y, z``: s, m, played in a loop), both from ``handle_motion.py``. The
path starts at the first handshake, so every session meets the same hand.
Every force command is answered as the device would:

* ``--protocol hapticlab``: our framed protocol (``framing.py``,
  ``docs/serial-protocol.md``): HELLO → HELLO_ACK, FORCE/HEARTBEAT → STATE,
  NAK for a bad CRC or a message out of place; the device clamps to its own
  maximum and zeroes its force when no valid frame arrives within the
  watchdog time the host asked for, as the reference firmware does.
* ``--protocol inverse3``: Haply's Inverse3 (``inverse3.py``): wake-up 0x0A →
  0x0B device info; force 0x2A → 0x2B end-effector state. Haply's own client,
  ``HaplyHardwareAPI``, talks to it.

Faults for tests and drills (methods here; ``--fault KIND@SECONDS[:ARG]`` on
the command line, ``master_emulator_cli.py``): corrupt the CRC of the next
replies (``corrupt_replies``), garbage before the next reply
(``garbage_before_reply``), stop answering and resume (``stop_answering``),
restart (``restart``: the device forgets the handshake), unplug (``unplug``:
the pty's master side closes; the slave path disappears and its reads fail
with EIO).
"""

from __future__ import annotations

import collections
import contextlib
import csv
import math
import os
import select
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hapticlab.core.host.options import choice
from hapticlab.plugins.haptics import framing, inverse3
from hapticlab.plugins.haptics.handle_motion import HandleMotion, scripted_motion
from hapticlab.plugins.pty_emulator import PtyEmulator


@dataclass
class EmulatorCounts:
    """What the emulated device has seen and done since it started."""

    frames: int = 0
    forces: int = 0
    heartbeats: int = 0
    hellos: int = 0
    naks_sent: int = 0
    crc_errors: int = 0
    garbage_bytes: int = 0
    watchdog_trips: int = 0
    clamped: int = 0
    replies_corrupted: int = 0
    requests_ignored: int = 0
    unknown_bytes: int = 0


class MasterEmulator(PtyEmulator):
    """A serial haptic master on a pty, in a thread of its own; a context manager (start/stop).

    Args:
        protocol: ``"hapticlab"`` or ``"inverse3"``.
        motion: the handle's motion (``scripted_motion`` or ``recorded_motion``); default a slow circle.
            Its time starts at the first handshake (the handle rests at the path's start before it), so a
            session sees the same hand whenever it connects (``path_time``).
        max_force: the device's own force limit, N (reported in the hapticlab HELLO_ACK).
        device_id: the device's id in its handshake answer.
        max_rate_hz: the command rate the device reports it keeps up with, Hz.
        buttons: t (s, the path's time) → the bit mask of pressed buttons (default none).
        keep: how many of the last forces received ``forces`` keeps.

    Attributes:
        port: the slave side's path (``/dev/pts/N``), the port to open.
        forces: the last ``keep`` forces received, each the (3,) float32 on the wire, N.
        received_ns: when each of ``forces`` came off the wire (``time.monotonic_ns()``, the clock a
            session's sample stamps use on this machine), ns.
        applied_force_D: (3,) the force the device renders now (after its clamp and watchdog), N.
        last_reply: (p_DoHo_D, v_DHo_D) as float32 in the last state sent.
        counts: EmulatorCounts.
    """

    def __init__(
        self,
        protocol: str = "hapticlab",
        motion: HandleMotion | None = None,
        max_force: float = 8.0,
        device_id: int = 0x4C41,
        max_rate_hz: float = 4000.0,
        buttons: Callable[[float], int] | None = None,
        keep: int = 100_000,
    ):
        choice("protocol", protocol, ("hapticlab", "inverse3"))
        self.protocol = protocol
        self.motion = motion or scripted_motion()
        self.max_force, self.device_id, self.max_rate_hz = max_force, device_id, max_rate_hz
        self.buttons = buttons or (lambda t: 0)
        self.uuid = uuid.UUID(int=0x4861_7074_6963_6C61_6200_0000_0000_0000 | device_id)
        self.counts = EmulatorCounts()
        self.forces: collections.deque[np.ndarray] = collections.deque(maxlen=keep)
        self.received_ns: collections.deque[int] = collections.deque(maxlen=keep)
        self.applied_force_D = np.zeros(3, np.float32)
        self.last_reply: tuple[np.ndarray, np.ndarray] | None = None
        self.port = ""
        self._master_fd = self._slave_fd = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._corrupt = 0
        self._garbage = b""
        self._silent = False
        self._unplug = threading.Event()
        self._unplugged = threading.Event()
        self._decoder = framing.FrameDecoder()
        self._seq = 0
        self._hello = False
        self._watchdog_s = 0.0
        self._last_valid = time.monotonic()
        self._status = 0
        self._inverse3_buffer = bytearray()
        self._t0 = time.monotonic()
        self._path_t0: float | None = None

    # ------------------------------------------------------------------ life cycle

    THREAD = "master-emulator"

    def _powered_on(self) -> None:
        self._t0 = time.monotonic()  # (scheduled faults count from here: ``now``)

    # ------------------------------------------------------------------ faults

    def corrupt_replies(self, n: int) -> None:
        """Flip a bit in the CRC of the next ``n`` replies (hapticlab) or their first byte (inverse3)."""
        with self._lock:
            self._corrupt += n

    def garbage_before_reply(self, data: bytes) -> None:
        """Write ``data`` just before the next reply (line noise, a boot banner)."""
        with self._lock:
            self._garbage += data

    def stop_answering(self, silent: bool = True) -> None:
        """Read and count requests without answering them (a hung firmware), or answer again."""
        with self._lock:
            self._silent = silent

    def restart(self) -> None:
        """Forget the handshake and zero the force, as a board reset by a brown-out (hapticlab protocol)."""
        with self._lock:
            self._hello = False
            self.applied_force_D = np.zeros(3, np.float32)

    def unplug(self) -> None:
        """Close the pty's master side, as a pulled USB cable: the port's reads and writes then fail."""
        self._unplug.set()
        if self._thread is not None and self._thread.is_alive():
            self._unplugged.wait(2.0)
        else:
            self._close_fds()

    # ------------------------------------------------------------------ serving

    def now(self) -> float:
        """Seconds since the emulator started (when scheduled faults fire)."""
        return time.monotonic() - self._t0

    def path_time(self) -> float:
        """Seconds since the first handshake, 0 before it: the time of the handle's path and buttons."""
        if self._path_t0 is None:
            return 0.0
        return time.monotonic() - self._path_t0

    def _greeted(self) -> None:
        if self._path_t0 is None:
            self._path_t0 = time.monotonic()

    def _serve(self) -> None:
        fd = self._master_fd
        while not self._stop.is_set():
            if self._unplug.is_set():
                self._close_fds()
                self._unplugged.set()
                return
            ready, _, _ = select.select([fd], [], [], 0.01)
            self._check_watchdog()
            if not ready:
                continue
            try:
                data = os.read(fd, 4096)
            except OSError:  # EIO: no process has the slave open at the moment
                time.sleep(0.005)
                continue
            t_ns = time.monotonic_ns()
            if self.protocol == "hapticlab":
                self._on_hapticlab(data, t_ns)
            else:
                self._on_inverse3(data, t_ns)

    def _write(self, reply: bytes) -> None:
        with self._lock:
            garbage, self._garbage = self._garbage, b""
            corrupt = self._corrupt > 0
            if corrupt:
                self._corrupt -= 1
                self.counts.replies_corrupted += 1
        if corrupt:
            reply = (
                reply[:-1] + bytes((reply[-1] ^ 0x01,))
                if self.protocol == "hapticlab"
                else bytes((reply[0] ^ 0x80,)) + reply[1:]
            )
        with contextlib.suppress(OSError):
            os.write(self._master_fd, garbage + reply)

    def _render(self, force: np.ndarray) -> np.ndarray:
        """The force the device's motors produce: clamped to its maximum along its direction, N."""
        norm = float(np.linalg.norm(force.astype(np.float64)))
        if not math.isfinite(norm):
            return np.zeros(3, np.float32)
        if norm > self.max_force:
            self.counts.clamped += 1
            self._status |= framing.STATUS_CLAMPED
            return (force * (self.max_force / norm)).astype(np.float32)
        return force

    def _state_now(self) -> tuple[np.ndarray, np.ndarray]:
        p, v = self.motion(self.path_time())
        p32, v32 = np.asarray(p, np.float32), np.asarray(v, np.float32)
        self.last_reply = (p32, v32)
        return p32, v32

    # hapticlab ------------------------------------------------------------

    def _check_watchdog(self) -> None:
        if (
            self.protocol == "hapticlab"
            and self._hello
            and self._watchdog_s > 0
            and time.monotonic() - self._last_valid > self._watchdog_s
            and self.applied_force_D.any()
        ):
            self.applied_force_D = np.zeros(3, np.float32)
            self._status |= framing.STATUS_WATCHDOG
            self.counts.watchdog_trips += 1

    def _nak(self, seq: int, code: int) -> None:
        self.counts.naks_sent += 1
        self._write(self._frame(framing.NAK, framing.NAK_FORMAT.pack(seq, code)))

    def _frame(self, kind: int, payload: bytes) -> bytes:
        self._seq = (self._seq + 1) & 0xFF
        return framing.encode_frame(kind, self._seq, payload)

    def _received(self, force: np.ndarray, t_ns: int) -> None:
        self.forces.append(force)
        self.received_ns.append(t_ns)
        self.counts.forces += 1
        self.applied_force_D = self._render(force)

    def write_forces(self, path: str | Path) -> int:
        """Write the forces received (``received_ns,fx,fy,fz``: ns, N) as CSV to a new ``path``; the row count."""
        with open(path, "x", newline="") as f:  # never over an existing file
            out = csv.writer(f)
            out.writerow(("received_ns", "fx", "fy", "fz"))
            rows = list(zip(self.received_ns, self.forces))
            out.writerows((t, *(repr(float(x)) for x in force)) for t, force in rows)
        return len(rows)

    def _on_hapticlab(self, data: bytes, t_ns: int) -> None:
        errors = self._decoder.crc_errors
        frames = self._decoder.feed(data)
        self.counts.garbage_bytes = self._decoder.garbage_bytes
        for _ in range(self._decoder.crc_errors - errors):
            self.counts.crc_errors += 1
            self._nak(0, framing.NAK_CRC)
        for frame in frames:
            self.counts.frames += 1
            if self._silent:
                self.counts.requests_ignored += 1
                continue
            expected = framing.PAYLOAD_SIZES.get(frame.kind)
            if expected is None or frame.kind >= 0x80:
                self._nak(frame.seq, framing.NAK_UNKNOWN_TYPE)
                continue
            if len(frame.payload) != expected:
                self._nak(frame.seq, framing.NAK_BAD_LENGTH)
                continue
            if frame.kind == framing.HELLO:
                version, watchdog_ms = framing.HELLO_FORMAT.unpack(frame.payload)
                if version != framing.PROTOCOL_VERSION:
                    self._nak(frame.seq, framing.NAK_VERSION)
                    continue
                self.counts.hellos += 1
                self._greeted()
                self._hello, self._watchdog_s = True, watchdog_ms / 1000.0
                self._last_valid = time.monotonic()
                self.applied_force_D = np.zeros(3, np.float32)
                ack = framing.HelloAck(framing.PROTOCOL_VERSION, self.device_id, 1, self.max_force, self.max_rate_hz)
                self._write(self._frame(framing.HELLO_ACK, ack.pack()))
                continue
            if not self._hello:
                self._nak(frame.seq, framing.NAK_NOT_READY)
                continue
            self._last_valid = time.monotonic()
            if frame.kind == framing.FORCE:
                self._received(framing.unpack_force(frame.payload), t_ns)
            else:
                self.counts.heartbeats += 1
            p, v = self._state_now()
            status, self._status = self._status, 0  # each status bit is reported once, in the next state
            state = framing.State(frame.seq, p, v, self.buttons(self.path_time()), status)
            self._write(self._frame(framing.STATE, state.pack()))

    # inverse3 -------------------------------------------------------------

    def _on_inverse3(self, data: bytes, t_ns: int) -> None:
        buf = self._inverse3_buffer
        buf += data
        while buf:
            code = buf[0]
            if code == inverse3.WAKEUP:
                del buf[:1]
                if self._silent:
                    self.counts.requests_ignored += 1
                    continue
                self.counts.hellos += 1
                self._greeted()
                info = inverse3.DeviceInfo(self.device_id, 3, 1, 1, self.uuid)
                self._write(info.pack())
            elif code == inverse3.END_EFFECTOR_FORCE:
                if len(buf) < inverse3.FORCE_REQUEST_SIZE:
                    return
                request = bytes(buf[: inverse3.FORCE_REQUEST_SIZE])
                del buf[: inverse3.FORCE_REQUEST_SIZE]
                self.counts.frames += 1
                if self._silent:
                    self.counts.requests_ignored += 1
                    continue
                self._received(inverse3.unpack_force_request(request), t_ns)
                p, v = self._state_now()
                self._write(inverse3.pack_state(p, v))
            else:  # a command this emulator does not implement: skipped, counted
                self.counts.unknown_bytes += 1
                del buf[:1]
