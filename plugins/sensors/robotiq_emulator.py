"""An emulated Robotiq FT 300 on a pseudo-terminal, fed by the simulated world.

It opens a pty pair (raw) and plays the sensor on the master side; the slave side (``/dev/pts/N``,
printed first by ``hapticlab emulate robotiq-ft300``) is the port a session, or any Modbus client
(``minimalmodbus``), opens as the sensor's USB-RS485 adapter. It speaks ``robotiq_protocol.py``:

* Modbus RTU as slave 9: FC03 (and FC04, the same registers) reads registers 180–185 (the newest
  reading), 500–502 (firmware version), 510–513 (serial number) and 514 (production year); another
  address is exception 02. FC16 writing 0x0200 to register 410 is answered with the FC16 echo and
  starts the stream; another value there is exception 03. A request with a bad CRC, or for another
  slave, gets no answer.
* The stream: a 16-byte frame every 10 ms of world time, until 50 0xFF bytes in a row arrive; while
  it streams, Modbus requests are ignored.

The readings are the ``sim`` sensor's at 100 Hz (the world's physics and its ``[[world.faults]]``),
quantised to 1/100 N and 1/1000 N·m and clipped to the wire's ±327.67 N and ±32.767 N·m. The
world's clock starts at the first byte a client sends, so a session that opens the port meets the
world from its start (as the master emulator's hand path starts at its handshake).

Faults for tests and drills, at world times (``--fault KIND@SECONDS[:ARG]``, or the methods):
``crc@T:N`` breaks the CRC of the next N frames (default 1), ``garbage@T:N`` writes N noise bytes
before the next frame (default 64), ``stall@T:D`` sends no frame for D s (default: for good; the
sensor samples on), ``unplug@T`` closes the pty (the port's reads fail, its path goes away).
"""

from __future__ import annotations

import collections
import os
import select
import threading
import time
from dataclasses import dataclass

import numpy as np

from hapticlab.plugins import scheduled_fault
from hapticlab.plugins.pty_emulator import PtyEmulator
from hapticlab.plugins.sensors import robotiq_protocol as rq
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.simworld.physics import SimWorld

FAULT_KINDS = ("crc", "garbage", "stall", "unplug")


@dataclass
class EmulatorCounts:
    """What the emulated sensor has seen and done since it started."""

    frames: int = 0
    frames_corrupted: int = 0
    frames_stalled: int = 0
    garbage_bytes: int = 0
    bytes_dropped: int = 0
    requests: int = 0
    exceptions: int = 0
    requests_ignored: int = 0
    starts: int = 0
    stops: int = 0


class ScheduledFault(scheduled_fault.ScheduledFault):
    """A fault injected once the world's time reaches ``at`` s (``KIND@SECONDS[:ARG]``)."""

    KINDS = FAULT_KINDS
    EXAMPLE = "crc@5:3 or stall@8:0.5"


class FT300Emulator(PtyEmulator):
    """A Robotiq FT 300 on a pty, served by a thread of its own; a context manager (start/stop).

    Args:
        world: the simulated world the sensor reads (its physics and faults).
        serial_number: registers 510–513, ``LLL-NNNN``.
        firmware: registers 500–502: three letters and three version numbers.
        production_year: register 514.
        faults: scheduled faults (:class:`ScheduledFault`), at world times.
        keep: how many of the last frames ``sent`` keeps.

    Attributes:
        port: the slave side's path (``/dev/pts/N``), the port to open.
        counts: :class:`EmulatorCounts`.
        sent: the last ``keep`` frames written: (world sample index, the six counts, whether its CRC was broken).
        t0_ns: ``time.monotonic_ns()`` of world time 0 (the first byte a client sent), None before.
        streaming: whether it streams.
    """

    def __init__(
        self,
        world: SimWorld,
        serial_number: str = "FTS-4242",
        firmware: tuple[str, tuple[int, int, int]] = ("FTS", (3, 0, 4)),
        production_year: int = 2026,
        faults: list[ScheduledFault] | tuple[ScheduledFault, ...] = (),
        keep: int = 20_000,
    ):
        self.world = world
        self.registers: dict[int, int] = {}
        for first, values in (
            (rq.REG_FIRMWARE, rq.text_registers(*firmware)),
            (rq.REG_SERIAL, rq.serial_number_registers(serial_number)),
            (rq.REG_YEAR, [int(production_year)]),
        ):
            self.registers.update(zip(range(first, first + len(values)), values))
        self.faults = sorted(faults, key=lambda f: f.at)
        self.counts = EmulatorCounts()
        self.sent: collections.deque[tuple[int, tuple[int, ...], bool]] = collections.deque(maxlen=keep)
        self.port = ""
        self.t0_ns: int | None = None
        self.streaming = False
        self._sensor = SimSensor(rq.STREAM_RATE_HZ, world=world)
        self._newest = np.zeros(6, dtype=np.int64)  # the newest reading, counts (registers 180-185)
        self._rx = bytearray()
        self._ff_run = 0
        self._corrupt = 0
        self._garbage = b""
        self._stall_until: float | None = None  # world time, s; inf: for good
        self._master_fd = self._slave_fd = -1
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._unplug = threading.Event()
        self._unplugged = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ life cycle

    THREAD = "ft300-emulator"
    NONBLOCKING = True

    def world_time(self) -> float:
        """The world's time, s: since the first byte a client sent (0 before)."""
        return 0.0 if self.t0_ns is None else (time.monotonic_ns() - self.t0_ns) * 1e-9

    # ------------------------------------------------------------------ faults

    def corrupt_frames(self, n: int = 1) -> None:
        """Flip a bit of the CRC of the next ``n`` frames."""
        with self._lock:
            self._corrupt += n

    def garbage_before_frame(self, data: bytes) -> None:
        """Write ``data`` just before the next frame (line noise)."""
        with self._lock:
            self._garbage += data

    def stall(self, seconds: float | None = None) -> None:
        """Send no frame for ``seconds`` of world time (None: for good); the sensor samples on."""
        with self._lock:
            self._stall_until = self.world_time() + (np.inf if seconds is None else seconds)

    def unplug(self) -> None:
        """Close the pty, as a pulled USB adapter: the port's reads fail and its path disappears."""
        self._unplug.set()
        if self._thread is not None and self._thread.is_alive():
            self._unplugged.wait(2.0)
        else:
            self._close_fds()

    def _due_faults(self) -> None:
        while self.faults and self.t0_ns is not None and self.world_time() >= self.faults[0].at:
            fault = self.faults.pop(0)
            if fault.kind == "crc":
                self.corrupt_frames(int(1 if fault.arg is None else fault.arg))
            elif fault.kind == "garbage":
                self.garbage_before_frame(os.urandom(int(64 if fault.arg is None else fault.arg)))
            elif fault.kind == "stall":
                self.stall(fault.arg)
            else:
                self._unplug.set()

    # ------------------------------------------------------------------ serving

    def _serve(self) -> None:
        period_ns = round(1e9 / rq.STREAM_RATE_HZ)
        while not self._stop.is_set():
            self._due_faults()
            if self._unplug.is_set():
                self._close_fds()
                self._unplugged.set()
                return
            now_ns = time.monotonic_ns()
            wait_s = 0.01
            if self.t0_ns is not None:
                wait_s = min(wait_s, max(0.0, (period_ns - (now_ns - self.t0_ns) % period_ns) * 1e-9))
            try:
                ready, _, _ = select.select([self._master_fd], [], [], wait_s)
                data = os.read(self._master_fd, 4096) if ready else b""
            except BlockingIOError:
                data = b""
            except OSError:  # EIO: no client holds the slave open at the moment
                time.sleep(0.005)
                continue
            if data and self.t0_ns is None:
                self.t0_ns = time.monotonic_ns()  # world time 0: the first byte a client sent
                self._sensor.open(self.t0_ns)
            if self.t0_ns is not None:
                self.sample_due(time.monotonic_ns())
            if data:
                self.receive(data)

    def sample_due(self, now_ns: int) -> None:
        """The readings due by now: the newest goes to registers 180-185; streaming, each is a frame."""
        block = self._sensor.read_block(now_ns)
        if not len(block):
            return
        counts = rq.counts_of(block.force_S, block.torque_S)
        self._newest = counts[-1]
        if not self.streaming:
            return
        with self._lock:
            stalled = self._stall_until is not None and self.world_time() < self._stall_until
            if stalled:
                self.counts.frames_stalled += len(counts)
                return
            out = bytearray(self._garbage)
            self.counts.garbage_bytes += len(self._garbage)
            self._garbage = b""
            for index, row in zip(block.seq.tolist(), counts.tolist()):
                frame = bytearray(rq.encode_frame(row))
                corrupt = self._corrupt > 0
                if corrupt:
                    self._corrupt -= 1
                    frame[-1] ^= 0x01
                    self.counts.frames_corrupted += 1
                out += frame
                self.sent.append((index, tuple(row), corrupt))
        self.counts.frames += len(counts)
        self._write(bytes(out))

    def _write(self, data: bytes) -> None:
        try:
            written = os.write(self._master_fd, data)
        except BlockingIOError:  # nobody reads the port: its buffer is full
            written = 0
        except OSError:
            return
        self.counts.bytes_dropped += len(data) - written

    def receive(self, data: bytes) -> None:
        """Bytes from the client: while streaming only a run of stop bytes is heard; else Modbus requests."""
        if self.streaming:  # only a run of 0xFF bytes is heard
            for byte in data:
                self._ff_run = self._ff_run + 1 if byte == rq.STOP_BYTE else 0
                if self._ff_run >= rq.STOP_COUNT:
                    self.streaming, self._ff_run = False, 0
                    self.counts.stops += 1
                    self._rx.clear()
            if self.streaming:
                self.counts.requests_ignored += 0 if data.count(rq.STOP_BYTE) == len(data) else 1
            return
        self._rx += data
        self._requests()

    def _requests(self) -> None:
        """Answer the complete requests in the receive buffer; skip a byte wherever none starts."""
        rx = self._rx
        while len(rx) >= 2:
            if rx[0] != rq.SLAVE_ID or rx[1] not in (rq.FC_READ, rq.FC_READ_INPUT, rq.FC_WRITE_MANY):
                del rx[0]  # not a request to this sensor (another slave, noise, a stop byte)
                continue
            size = 8 if rx[1] != rq.FC_WRITE_MANY else (9 + rx[6] if len(rx) >= 7 else 0)
            if not size or len(rx) < size:
                return
            request = bytes(rx[:size])
            if rq.crc16(request[:-2]) != int.from_bytes(request[-2:], "little"):
                del rx[0]
                continue
            del rx[:size]
            self.counts.requests += 1
            self._write(self._answer(request))

    def _answer(self, request: bytes) -> bytes:
        function = request[1]
        address, count = int.from_bytes(request[2:4], "big"), int.from_bytes(request[4:6], "big")
        if function in (rq.FC_READ, rq.FC_READ_INPUT):
            values = [self._register(a) for a in range(address, address + count)]
            if count < 1 or count > 125 or None in values:
                return self._exception(function, 2)
            data = b"".join(int(v).to_bytes(2, "big") for v in values)  # type: ignore[arg-type]  # None refused above
            return rq.with_crc(bytes((rq.SLAVE_ID, function, len(data))) + data)
        if address != rq.REG_STREAM or count != 1 or request[6] != 2:
            return self._exception(function, 2)
        if int.from_bytes(request[7:9], "big") != rq.STREAM_START:
            return self._exception(function, 3)
        self.streaming = True
        self._ff_run = 0
        self.counts.starts += 1
        return rq.with_crc(request[:6])

    def _register(self, address: int) -> int | None:
        if rq.REG_FORCE <= address < rq.REG_FORCE + 6:
            return int(self._newest[address - rq.REG_FORCE]) & 0xFFFF
        return self.registers.get(address)

    def _exception(self, function: int, code: int) -> bytes:
        self.counts.exceptions += 1
        return rq.with_crc(bytes((rq.SLAVE_ID, function | 0x80, code)))
