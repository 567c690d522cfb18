"""A Bota Systems serial F/T sensor (BFT-*-SER) on a pseudo-terminal, fed by the simulated world.

It speaks the wire of ``bota_protocol.py``: after its start (power-on) it writes ``App Init``
and streams frames in run mode at its default rate; ``C`` stops the stream (configuration
mode, ``r,0,C,0``), ``c,T,K,D,B`` and ``f,S,C,F,D`` set the communication and the filter (the
sinc length sets the rate, 51 200 / S Hz), ``R`` runs again (``r,0,R,0``). The frames carry the
world's wrench (float32, N and N·m), the device timestamp (µs since the emulator started, on
its own sample grid) and a temperature that warms up from ``temperature_C`` by ``warm_up_C``
with time constant ``warm_up_s`` (a board warming in its housing). A reading the world
saturated sets the overrange bit, a non-finite one the invalid-measurements bit.

The world's clock starts at the first ``R``, as the master emulator's hand starts at the
first handshake: a session that configures the sensor and runs it meets the world from its
start (before it, the frames carry the world at time 0). Frames go out in bursts about once a
millisecond, timed from the monotonic clock; bytes no one reads are lost as on a real UART
(``counts.unsent_bytes``). Faults (methods here; ``--fault`` in ``bota_emulator_cli.py``):
corrupt the CRC of the next frames, noise bytes, status bits for a while, a stalled stream,
unplug. Departures from the real sensor: docs/devices.md.
"""

from __future__ import annotations

import math
import os
import re
import select
import threading
import time
from dataclasses import dataclass

import numpy as np

from hapticlab.core.types import STATUS_SATURATED
from hapticlab.plugins.pty_emulator import PtyEmulator
from hapticlab.plugins.sensors import bota_protocol as bp
from hapticlab.plugins.simworld.faults import apply_sensor_faults
from hapticlab.plugins.simworld.physics import SimWorld

BURST_S = 0.001
"""Frames go out in bursts this far apart, s."""
QUIET_S = 0.005
"""A ``c``/``f`` command whose last number is at the end of what arrived is taken after this long without a
byte, s (Bota's example sends no terminator)."""
_COMMAND = re.compile(rb"([CR])|([cf]),(\d+),(\d+),(\d+),(\d+)")


@dataclass
class EmulatorCounts:
    """What the emulated sensor did since it started."""

    frames: int = 0
    commands: int = 0
    refused: int = 0
    unknown_bytes: int = 0
    corrupted: int = 0
    garbage_bytes: int = 0
    status_frames: int = 0
    stalled_frames: int = 0
    unsent_bytes: int = 0


class BotaEmulator(PtyEmulator):
    """A Bota serial sensor on a pty, served by a thread; a context manager (start/stop).

    Args:
        world: the simulated world the sensor sits in (its physics and ``[[world.faults]]``).
        sinc_length: the filter's sinc length at power-on (the rate: 51 200 / sinc_length Hz; 64: 800 Hz).
        temperature_C: the board's temperature at power-on, °C.
        warm_up_C: how much it warms up, °C (0: constant).
        warm_up_s: the warm-up's time constant, s.

    Attributes:
        port: the slave side's path (``/dev/pts/N``), the port to open.
        received: every byte the sensor got (the host's commands), for a look at what a client sends.
        sinc_length, running, calibration, temperature_compensation: the settings in force.
        run_ns: monotonic time of the first ``R`` (world time 0), ns; None before it.
        counts: EmulatorCounts.
    """

    def __init__(
        self,
        world: SimWorld,
        sinc_length: int = 64,
        temperature_C: float = 28.0,
        warm_up_C: float = 3.0,
        warm_up_s: float = 600.0,
    ):
        if not bp.SINC_LENGTHS[0] <= sinc_length <= bp.SINC_LENGTHS[1]:
            raise ValueError(f"sinc_length: must be in {bp.SINC_LENGTHS[0]}..{bp.SINC_LENGTHS[1]}, got {sinc_length}")
        self.world = world
        self.sinc_length = int(sinc_length)
        self.temperature = (float(temperature_C), float(warm_up_C), float(warm_up_s))
        self.running = True  # a sensor powers on streaming with its stored settings
        self.calibration, self.temperature_compensation = True, False
        self.received = bytearray()
        self.counts = EmulatorCounts()
        self.port = ""
        self.boot_ns = self.origin_ns = 0
        self.run_ns: int | None = None
        self._next = 0  # the next sample's index on the grid from origin_ns
        self._master_fd = self._slave_fd = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._text = bytearray()
        self._last_byte = 0.0
        self._corrupt = 0
        self._garbage = b""
        self._status_until: list[tuple[int, float]] = []  # (bits, monotonic s)
        self._stall_until = 0.0
        self._unplug = threading.Event()

    # ------------------------------------------------------------------ life cycle

    THREAD = "bota-emulator"
    NONBLOCKING = True

    def _powered_on(self) -> None:
        """Power on: ``App Init``, then streaming."""
        self.boot_ns = self.origin_ns = time.monotonic_ns()
        self._write(b"\r\n" + bp.APP_INIT + b"\r\n")

    @property
    def rate_hz(self) -> float:
        """The sample rate in force, Hz."""
        return bp.rate_of(self.sinc_length)

    def world_time(self, timestamp_us: np.ndarray) -> np.ndarray:
        """The world time of frames with these (unwrapped) device timestamps, s (0 before the first ``R``)."""
        if self.run_ns is None:
            return np.zeros(np.shape(timestamp_us))
        return np.maximum(0.0, np.asarray(timestamp_us) * 1e-6 - (self.run_ns - self.boot_ns) * 1e-9)

    def run_timestamps_us(self, index: np.ndarray) -> np.ndarray:
        """The device timestamps (µs, unwrapped) of the frames ``index`` (0, 1, ...) of the current run."""
        t_ns = self.origin_ns + np.rint(np.asarray(index) * (1e9 / self.rate_hz)).astype(np.int64)
        return np.rint((t_ns - self.boot_ns) * 1e-3).astype(np.int64)

    # ------------------------------------------------------------------ faults

    def corrupt_frames(self, n: int) -> None:
        """Flip a bit in the CRC of the next ``n`` frames."""
        with self._lock:
            self._corrupt += n

    def garbage(self, data: bytes) -> None:
        """Write ``data`` into the stream before the next frame (line noise)."""
        with self._lock:
            self._garbage += data

    def set_status(self, bits: int, duration_s: float) -> None:
        """OR ``bits`` into the status word of the frames of the next ``duration_s`` seconds."""
        with self._lock:
            self._status_until.append((bits, time.monotonic() + duration_s))

    def stall(self, duration_s: float) -> None:
        """Send nothing for ``duration_s`` seconds (the samples of that while are never sent)."""
        with self._lock:
            self._stall_until = time.monotonic() + duration_s

    def unplug(self) -> None:
        """Close the pty's master side, as a pulled cable: the port's reads then fail."""
        self._unplug.set()
        if self._thread is None:
            self._close_fds()

    # ------------------------------------------------------------------ serving

    def _serve(self) -> None:
        burst_ns = int(BURST_S * 1e9)
        due_ns = self.boot_ns
        while not self._stop.is_set():
            if self._unplug.is_set():
                self._close_fds()
                return
            now_ns = time.monotonic_ns()
            if now_ns >= due_ns:
                self._burst(now_ns)
                due_ns = max(due_ns + burst_ns, now_ns)
            try:
                ready, _, _ = select.select([self._master_fd], [], [], max(0.0, (due_ns - now_ns) * 1e-9))
                data = os.read(self._master_fd, 4096) if ready else b""
            except BlockingIOError:
                data = b""
            except OSError:  # EIO while no process holds the slave side: nothing to read
                time.sleep(0.001)
                data = b""
            if data:
                self.received += data
                self._text += data.translate(None, b" \t\r\n")  # a newline after a command (bota-driver's) ends it
                self._last_byte = time.monotonic()
            if self._text:
                self._commands()

    def _commands(self) -> None:
        """Act on every complete command in the text received (unknown bytes before one are counted and skipped)."""
        while self._text:
            match = _COMMAND.search(self._text)
            if match is None:
                if not re.fullmatch(rb"[cf][,\d]*", self._text):  # no command is starting here
                    self.counts.unknown_bytes += len(self._text)
                    self._text.clear()
                return
            if match.group(2) and match.end() == len(self._text) and time.monotonic() - self._last_byte < QUIET_S:
                return  # its last number may go on
            letter = bytes(match.group(1) or match.group(2))
            numbers = [int(g) for g in match.groups()[2:] if g is not None]
            self.counts.unknown_bytes += match.start()
            del self._text[: match.end()]  # (the match's groups are views of this buffer: read above)
            self.counts.commands += 1
            self._command(letter, numbers)

    def _command(self, letter: bytes, numbers: list[int]) -> None:
        name = letter.decode()
        if name == "C":
            self.running = False
        elif name == "R":
            now = time.monotonic_ns()
            if self.run_ns is None:
                self.run_ns = now
            self.running, self.origin_ns, self._next = True, now, 0
        elif self.running:  # settings only in configuration mode
            self.counts.refused += 1
            self._write(bp.reply(name, 1))
            return
        elif name == "c":
            compensation, calibration, data_format, baud = numbers
            if data_format != 0 or baud != bp.BAUD_INDEX[bp.BAUDRATE] or compensation > 1 or calibration > 1:
                self.counts.refused += 1  # CSV frames and other baud rates: not emulated
                self._write(bp.reply(name, 1))
                return
            self.temperature_compensation, self.calibration = bool(compensation), bool(calibration)
        else:
            if not bp.SINC_LENGTHS[0] <= numbers[0] <= bp.SINC_LENGTHS[1]:
                self.counts.refused += 1
                self._write(bp.reply(name, 1))
                return
            self.sinc_length = numbers[0]
        self._write(bp.reply(name))

    def _burst(self, now_ns: int) -> None:
        """The frames whose time has come, when running."""
        if not self.running:
            return
        period_ns = 1e9 / self.rate_hz
        last = math.floor((now_ns - self.origin_ns) / period_ns)
        if last < self._next:
            return
        index = np.arange(self._next, last + 1)
        self._next = last + 1
        t_ns = self.origin_ns + np.rint(index * period_ns).astype(np.int64)
        device_us = self.run_timestamps_us(index)
        t = self.world_time(device_us)
        reading = self.world.wrench(t)
        force_S, torque_S = reading["force_S"].copy(), reading["torque_S"].copy()
        status = np.where(reading["status"] & STATUS_SATURATED, bp.STATUS_OVERRANGE, 0).astype(np.int64)
        sensor = {"force_S": force_S, "torque_S": torque_S, "status": reading["status"].copy()}
        keep = apply_sensor_faults(self.world.faults, t, sensor) if self.world.faults else np.ones(len(t), bool)
        status |= np.where(sensor["status"] & STATUS_SATURATED, bp.STATUS_OVERRANGE, 0)
        finite = np.isfinite(force_S).all(axis=1) & np.isfinite(torque_S).all(axis=1)
        status |= np.where(finite, 0, bp.STATUS_INVALID)
        if not self.calibration:
            status |= bp.STATUS_RAW
        clock = time.monotonic()
        with self._lock:
            self._status_until = [(bits, until) for bits, until in self._status_until if until > clock]
            for bits, _ in self._status_until:
                status |= bits
            if clock < self._stall_until:
                self.counts.stalled_frames += int(keep.sum())
                return
            garbage, self._garbage = self._garbage, b""
            corrupt, self._corrupt = min(self._corrupt, int(keep.sum())), max(0, self._corrupt - int(keep.sum()))
        temperature = self._temperature((t_ns - self.boot_ns) * 1e-9)
        frames = bytearray(
            bp.encode_frames(status[keep], force_S[keep], torque_S[keep], device_us[keep], temperature[keep])
        )
        for i in range(corrupt):
            frames[(i + 1) * bp.FRAME_SIZE - 1] ^= 0x01
        self.counts.frames += int(keep.sum())
        self.counts.corrupted += corrupt
        self.counts.garbage_bytes += len(garbage)
        self.counts.status_frames += int(np.count_nonzero(status[keep]))
        self._write(garbage + bytes(frames))

    def _temperature(self, since_boot_s: np.ndarray) -> np.ndarray:
        start, rise, tau = self.temperature
        return start + rise * (1.0 - np.exp(-since_boot_s / tau)) if rise else np.full(len(since_boot_s), start)

    def _write(self, data: bytes) -> None:
        """Write to the port; what the pty cannot take now is lost, as on a UART no one reads."""
        try:
            written = os.write(self._master_fd, data)
        except (BlockingIOError, OSError):
            written = 0
        self.counts.unsent_bytes += len(data) - written
