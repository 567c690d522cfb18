"""hapticlab's own receiver of the ATI Net F/T's RDT stream, for the ``netft`` sensor (``receiver = "hapticlab"``).

Why not pynetft here: pynetft (the community client, still used for
``receiver = "pynetft"``) builds Python objects for every record on its own
thread, and it stops and reconnects the stream whenever a record's status
word reports an error (saturation included): a blackout for every saturated
record (what that costs: docs/devices.md).

What this module does instead:

* **A UDP socket connected to the sensor** (the kernel drops datagrams from
  any other address), with a large ``SO_RCVBUF``, and the RDT requests of
  ``netft_protocol.py``.
* **No thread**: :meth:`RdtReceiver.poll` (called once per loop tick) drains the
  socket with ``recv_into`` into one preallocated buffer until it would
  block, then reads every record of the tick with one ``np.frombuffer`` of a
  big-endian structured dtype. A datagram of any whole number of 36-byte
  records is accepted (real-time and buffered mode alike).
* **Health counted on the batch, vectorised** (:data:`COUNTER_DOC`).
* **A status word never stops the stream**: a saturated record reaches the
  stream with its status bits, so the haptic force is zero for exactly the
  bad samples.
"""

from __future__ import annotations

import contextlib
import socket
import time
from dataclasses import dataclass

import numpy as np

from hapticlab.plugins.sensors.netft_protocol import (
    CMD_START,
    CMD_STOP,
    RDT_HEADER,
    RDT_PORT,
    RECORD_DTYPE,
    RECORD_SIZE,
    stream_status_array,
)

MAX_DATAGRAM = 64 * RECORD_SIZE
"""Largest datagram read whole, bytes (ATI's buffered mode sends at most 40 records); a longer one is malformed."""
REWIND = 1024
"""A record this many rdt_sequence numbers behind, numbered at most this, starts a new stream (a start request)."""
REWIND_ASKED = 16
"""... or only this many behind, within 2·REWIND records after our own start request: a start request
still in flight may renumber the stream once more after its records have come back."""

MAX_JUMP = 1 << 16
"""A record numbered this far ahead of the stream (rdt_sequence), or sampled this far ahead (ft_sequence: 9.4 s
at 7 kHz), is damaged, not late news: a loss that long ends in a receive timeout and a new stream."""

COUNTER_DOC = {
    "received": "records received (duplicates and late ones included)",
    "lost": "rdt_sequence numbers the stream skipped: records dropped on the way, or arriving too late "
    "to be delivered in order (those also count as late)",
    "duplicate": "records whose rdt_sequence had already been received (not delivered)",
    "out_of_order": "records (duplicates aside) that arrived after one with a higher rdt_sequence; "
    "delivered in order when they arrive in the same read, else late",
    "late": "out-of-order records that arrived after the stream had passed them (not delivered)",
    "stall": "records repeating the previous ft_sequence: the sensor's sampling stalled (not delivered)",
    "ft_backward": "records whose ft_sequence went back within one stream (not delivered)",
    "ft_restart": "the sensor restarted its counter: a new stream's ft_sequence behind the last one",
    "malformed": "datagrams that are not a whole number of 36-byte records",
    "corrupt": "records numbered or sampled more than MAX_JUMP ahead of the stream: damaged (not delivered)",
    "timeout": "receive timeouts (no record for receive_timeout)",
    "reconnect": "start requests sent again after a timeout",
    "device_error": "delivered records with an error bit in their status word",
    "warning": "delivered records with only a threshold monitor bit in their status word",
    "queue_dropped": "always 0: no queue (a full socket buffer shows as lost)",
    "calibration_change": "always 0: the calibration is read once, at open",
}
"""The receiver's health counters and what they count, since ``open``."""


@dataclass(slots=True)
class RdtBatch:
    """The records of one poll that reach the stream, in order.

    Attributes:
        k: (n,) int64 unwrapped ft_sequence (the device's sample number).
        status: (n,) int64 ATI status words.
        values: (n, 6) counts, Fx Fy Fz Tx Ty Tz.
        received_ns: when they were read, monotonic ns: one time (the drain), or (n,) int64 one per record.
        restarts: (index, old ft_sequence, new ft_sequence) where the sensor restarted its counter.
    """

    k: np.ndarray
    status: np.ndarray
    values: np.ndarray
    received_ns: int | np.ndarray
    restarts: list[tuple[int, int, int]]


class RdtReceiver:
    """An RDT client on one connected UDP socket, drained without a thread.

    Parameters
    ----------
    address, port : the sensor's IP address (or host name) and RDT port.
    rcvbuf_bytes : the socket receive buffer asked for, bytes (the kernel caps it at
        ``net.core.rmem_max`` and doubles it; :attr:`rcvbuf_bytes` is what it granted).
    capacity : records one poll reads at most (the rest wait in the socket for the next).
    """

    def __init__(self, address: str, port: int = RDT_PORT, rcvbuf_bytes: int = 4 << 20, capacity: int = 16384):
        self.address, self.port = address, port
        self.counters = dict.fromkeys(COUNTER_DOC, 0)
        """The health counters since :meth:`open` (:data:`COUNTER_DOC`)."""
        self._buffer = bytearray(capacity * RECORD_SIZE + MAX_DATAGRAM + 1)
        self._view = memoryview(self._buffer)
        self._rcvbuf_asked = rcvbuf_bytes
        self.rcvbuf_bytes = 0
        self._sock: socket.socket | None = None
        self._rdt: int | None = None  # the highest rdt_sequence received in this stream, as sent
        self._r = 0  # ... unwrapped
        self._ft: int | None = None  # the ft_sequence of the newest delivered record, as sent
        self._k = 0  # ... unwrapped
        self._new_stream = True
        self._asked_left = 0  # records for which a small rewind still means our last start request took effect
        self._holes: list[tuple[int, int]] = []  # recent gaps [lo, hi] in unwrapped rdt_sequence
        self._steps = np.arange(1, capacity + MAX_DATAGRAM // RECORD_SIZE + 1)

    def open(self) -> None:
        """Connect the socket and send the start request (real-time mode, until stopped)."""
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self._rcvbuf_asked)
        self.rcvbuf_bytes = self._sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self._sock.connect((self.address, self.port))
        self._sock.setblocking(False)
        self.request(CMD_START)

    def request(self, command: int, count: int = 0) -> None:
        """Send an RDT request (``CMD_START``, ``CMD_START_BUFFERED``, ``CMD_STOP``, ``CMD_BIAS``)."""
        with contextlib.suppress(OSError):  # ICMP unreachable from an earlier send, or no route: the timeout will tell
            self._sock.send(RDT_HEADER.to_bytes(2, "big") + command.to_bytes(2, "big") + count.to_bytes(4, "big"))  # type: ignore[union-attr]  # open() made it

    def restart(self) -> None:
        """Send the start request again (after a receive timeout); the sensor numbers rdt_sequence from 1 again."""
        self.counters["reconnect"] += 1
        self._asked_left = 2 * REWIND  # a rewind by more than REWIND_ASKED to at most REWIND is a new stream
        self.request(CMD_START)

    def wait(self, timeout: float) -> bool:
        """Block until a datagram is waiting, at most ``timeout`` s (for ``open``; never in the loop)."""
        self._sock.settimeout(timeout)  # type: ignore[union-attr]  # open() made it
        try:
            self._sock.recv(1, socket.MSG_PEEK)  # type: ignore[union-attr]  # open() made it
            return True
        except OSError:
            return False
        finally:
            self._sock.setblocking(False)  # type: ignore[union-attr]  # open() made it

    def close(self) -> None:
        """Send the stop request and close the socket."""
        if self._sock is not None:
            self.request(CMD_STOP)
            self._sock.close()
            self._sock = None

    # ------------------------------------------------------------------ the stream

    def drain(self) -> np.ndarray:
        """Every record waiting in the socket (up to ``capacity``): a structured view of the buffer, valid until
        the next drain."""
        view, size, limit = self._view, 0, len(self._buffer) - MAX_DATAGRAM - 1
        recv_into = self._sock.recv_into  # type: ignore[union-attr]  # open() made it
        while size <= limit:
            try:
                n = recv_into(view[size:], MAX_DATAGRAM + 1)  # one byte more: a truncated datagram shows
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:  # an ICMP "port unreachable" for an earlier request: nobody there
                break
            if n == 0 or n % RECORD_SIZE:
                self.counters["malformed"] += 1
                continue  # not kept: the next datagram overwrites it
            size += n
        return np.frombuffer(self._buffer, RECORD_DTYPE, size // RECORD_SIZE)

    def poll(self) -> RdtBatch | None:
        """Drain the socket; the records that reach the stream, with the health counters updated.

        Their receive time is the clock read once the socket is empty: every record was there before it
        (a time read before draining could precede a record that came during the drain).
        """
        records = self.drain()
        now_ns = time.monotonic_ns()
        n = len(records)
        if n == 0:
            return None
        self.counters["received"] += n
        rdt = records["rdt_sequence"].astype(np.int64)
        ft = records["ft_sequence"].astype(np.int64)
        status = records["status"].astype(np.int64)
        values = records["counts"]
        if self._rdt is not None and not self._new_stream:  # the usual tick: consecutive records, ft forward
            d_ft = np.empty(n, dtype=np.int64)
            d_ft[0] = ft[0] - self._ft
            np.subtract(ft[1:], ft[:-1], out=d_ft[1:])
            d_ft &= 0xFFFF_FFFF
            consecutive = ((rdt - self._rdt) & 0xFFFF_FFFF == self._steps[:n]).all()
            if consecutive and ((d_ft - 1) & 0xFFFF_FFFF < MAX_JUMP).all():  # every ft step in [1, MAX_JUMP]
                k = np.cumsum(d_ft)
                k += self._k
                self._rdt, self._r, self._ft, self._k = int(rdt[-1]), self._r + n, int(ft[-1]), int(k[-1])
                self._count_status(status)
                if self._asked_left > 0:
                    self._asked_left -= n
                return RdtBatch(k, status, values.astype(np.float64), now_ns, [])
        index, k, restarts = self._sort_out(rdt, ft)
        status = status[index]
        self._count_status(status)
        return RdtBatch(k, status, values[index].astype(np.float64), now_ns, restarts)

    def _count_status(self, status: np.ndarray) -> None:
        if status.any():
            bits = stream_status_array(status)
            self.counters["device_error"] += int(np.count_nonzero(bits))
            self.counters["warning"] += int(np.count_nonzero((status != 0) & (bits == 0)))

    def _sort_out(self, rdt: np.ndarray, ft: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
        """The slow path (a fault in the batch): which records reach the stream, in rdt_sequence order.

        Returns the indices of the records delivered, their unwrapped ft_sequence, and the restarts.
        """
        # a record far behind (REWIND, or REWIND_ASKED after our start request) numbered at most REWIND starts
        # a new stream: the sensor numbers rdt_sequence from 1 after every start request
        previous = np.concatenate([[self._rdt if self._rdt is not None else rdt[0]], rdt[:-1]])
        behind = (previous - rdt) & 0xFFFF_FFFF
        far = REWIND_ASKED if self._asked_left > 0 else REWIND
        self._asked_left -= len(rdt)
        starts = np.flatnonzero((behind > far) & (behind < 2**31) & (rdt <= REWIND))
        bounds = ([0] if self._rdt is None else []) + starts.tolist()
        segments = [(a, b) for a, b in zip([0] + bounds, bounds + [len(rdt)]) if b > a]
        index: list[np.ndarray] = []
        k: list[np.ndarray] = []
        restarts: list[tuple[int, int, int]] = []
        for a, b in segments:
            if a in bounds:  # a new stream: anchor just before its first record
                self._rdt, self._r, self._holes, self._new_stream = int(rdt[a] - 1) & 0xFFFF_FFFF, 0, [], True
            i, kk = self._segment(rdt[a:b], ft[a:b], restarts, sum(len(x) for x in index))
            index.append(i + a)
            k.append(kk)
        return np.concatenate(index), np.concatenate(k), restarts

    def _segment(self, rdt, ft, restarts, offset) -> tuple[np.ndarray, np.ndarray]:
        c = self.counters
        r = self._r + (((rdt - self._rdt + 2**31) & 0xFFFF_FFFF) - 2**31)  # unwrapped around the anchor
        corrupt = r - self._r > MAX_JUMP
        c["corrupt"] += int(np.count_nonzero(corrupt))
        r = np.where(corrupt, self._r, r)  # passed already, not a hole's: counted as corrupt only, below
        inverted = r < np.maximum.accumulate(np.concatenate([[self._r], r[:-1]]))  # after a higher one
        duplicate = np.zeros(len(r), dtype=bool)
        old = np.flatnonzero(r <= self._r)
        old = old[~corrupt[old]]
        for i, ri in zip(old.tolist(), r[old].tolist()):  # passed already: a duplicate, or late for its hole
            hole = next((j for j, (lo, hi) in enumerate(self._holes) if lo <= ri <= hi), None)
            if hole is None:
                duplicate[i] = True
                continue
            c["late"] += 1
            lo, hi = self._holes.pop(hole)
            self._holes[hole:hole] = [h for h in ((lo, ri - 1), (ri + 1, hi)) if h[0] <= h[1]]
        fresh = np.flatnonzero(r > self._r)
        fresh = fresh[np.argsort(r[fresh], kind="stable")]
        repeated = np.zeros(len(fresh), dtype=bool)  # the later arrivals of a number (none when fresh is empty)
        repeated[1:] = r[fresh][1:] == r[fresh][:-1]
        duplicate[fresh[repeated]] = True
        c["duplicate"] += int(np.count_nonzero(duplicate))
        c["out_of_order"] += int(np.count_nonzero(inverted & ~duplicate & ~corrupt))  # each counts as one thing
        fresh = fresh[~repeated]
        if len(fresh) == 0:
            return fresh, np.zeros(0, np.int64)
        rs = r[fresh]
        gaps = np.diff(rs, prepend=self._r) - 1
        c["lost"] += int(gaps.sum())
        for hi, gap in zip((rs[gaps > 0] - 1).tolist(), gaps[gaps > 0].tolist()):
            self._holes.append((hi - gap + 1, hi))
        del self._holes[:-256]
        self._rdt, self._r = int(rdt[fresh[-1]]), int(rs[-1])
        f = ft[fresh]
        if self._ft is None:  # the first record: k is its ft_sequence as sent
            self._ft, self._k = int(f[0] - 1) & 0xFFFF_FFFF, int(f[0]) - 1
        kk = self._k + (((f - self._ft + 2**31) & 0xFFFF_FFFF) - 2**31)
        if self._new_stream and kk[0] < self._k:  # a new stream behind the old one: the sensor restarted
            c["ft_restart"] += 1
            restarts.append((offset, self._ft, int(f[0])))
            kk += self._k + 1 - kk[0]
        self._new_stream = False
        sampled_ahead = kk - self._k > MAX_JUMP
        c["corrupt"] += int(np.count_nonzero(sampled_ahead))
        kk = np.where(sampled_ahead, self._k, kk)  # never kept (kk > before fails), never anyone's "before"
        before = np.maximum.accumulate(np.concatenate([[self._k], kk[:-1]]))
        c["stall"] += int(np.count_nonzero((kk == before) & ~sampled_ahead))
        c["ft_backward"] += int(np.count_nonzero((kk < before) & ~sampled_ahead))
        keep = kk > before
        if keep.any():
            newest = int(np.argmax(kk))
            self._ft, self._k = int(f[newest]), int(kk[newest])
        return fresh[keep], kk[keep]
