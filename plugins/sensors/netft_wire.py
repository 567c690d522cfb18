"""The emulated Net F/T's end of the RDT wire: each record numbered, put through the wire faults, sent, counted.

A wire fault (:class:`RdtFault`) is what a network or a device does wrong to
the stream: dropped, duplicated and reordered records, status bits, a stalled
``ft_sequence``, saturated counts. Each is active over a window of world time
and hits every ``every``-th record in it; ``hapticlab emulate netft --fault``
and ``emulate lab --netft-fault`` take them as
``kind[,start=S][,duration=S][,every=N][,status=0x...]`` (:meth:`RdtFault.parse`).
:class:`RdtSender` applies them as the emulator (``netft_emulator.py``) sends
each record, and counts what it did (:class:`EmulatorCounts`).
"""

from __future__ import annotations

import math
import socket
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.host.options import OptionError, choice, integer, number
from hapticlab.plugins.sensors.netft_protocol import ATI_ERROR_SUMMARY, ATI_SATURATION, RECORD

FAULT_KINDS = ("drop", "duplicate", "reorder", "status", "stall", "saturate")
"""The wire faults the emulator injects (:class:`RdtFault`)."""
INT32_MAX = 2**31 - 1


@dataclass(frozen=True, slots=True)
class RdtFault:
    """A fault on the wire, active for records whose world time is in [start, start + duration).

    Attributes:
        kind: ``drop`` (record not sent; its rdt_sequence is used up), ``duplicate``
            (sent twice), ``reorder`` (sent after the next record), ``status`` (``status``
            bits OR-ed into the status word), ``stall`` (the device repeats its last
            ft_sequence and counts: its sampling stalled), ``saturate`` (every axis at its
            saturation counts, status saturation and error summary bits).
        start: world time the fault starts, s.
        duration: how long it lasts, s.
        every: it hits every ``every``-th record while active (1: each one).
        status: the status bits of a ``status`` fault.
    """

    kind: str
    start: float = 0.0
    duration: float = math.inf
    every: int = 1
    status: int = 0

    def __post_init__(self) -> None:
        choice("kind", self.kind, FAULT_KINDS)
        number("start", self.start, minimum=0, hint=" s")
        number("duration", self.duration, above=0, finite=False, hint=" s")
        integer("every", self.every, minimum=1)
        if self.kind == "status" and not (isinstance(self.status, int) and 0 < self.status <= 0xFFFF_FFFF):
            raise OptionError("status", f"must be the bits to set, a nonzero 32-bit word, got {self.status!r}")

    def hits(self, t: float, index: int) -> bool:
        """Whether the record at world time ``t`` s (the ``index``-th record sent) is hit."""
        return self.start <= t < self.start + self.duration and index % self.every == 0

    @classmethod
    def parse(cls, text: str) -> RdtFault:
        """``kind[,start=S][,duration=S][,every=N][,status=0x...]`` (the ``--fault`` syntax)."""
        kind, *fields = [f.strip() for f in text.split(",")]
        values: dict[str, Any] = {}  # start, duration: float; every, status: int
        try:
            for field in fields:
                key, sep, value = field.partition("=")
                if not sep or key not in ("start", "duration", "every", "status"):
                    raise ValueError("expected key=value with key start, duration, every or status")
                try:
                    values[key] = int(value, 0) if key in ("every", "status") else float(value)
                except ValueError:
                    what = {"every": "a whole number", "status": "a 32-bit word (e.g. 0x80020000)"}.get(
                        key, "a number of s"
                    )
                    raise OptionError(key, f"must be {what}, got {value!r}") from None
            return cls(kind, **values)
        except ValueError as exc:
            raise ValueError(f"fault {text!r}: {exc}") from None


@dataclass
class EmulatorCounts:
    """What the emulator did on the wire since it started (for tests and the operator).

    Attributes: records ``sent`` (datagrams, duplicates included), ``dropped``,
    ``duplicated``, ``reordered`` (records sent late), ``stalled`` (records repeating the
    last ft_sequence), ``status`` (records with a nonzero status word), ``starts``,
    ``stops`` and ``biases`` (requests obeyed), ``ignored`` (bad requests).
    """

    sent: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    stalled: int = 0
    status: int = 0
    starts: int = 0
    stops: int = 0
    biases: int = 0
    ignored: int = 0


class RdtSender:
    """The sending end of the emulated RDT stream (called under the emulator's lock).

    Parameters
    ----------
    sock : the emulator's UDP socket.
    faults : the wire faults to inject.
    saturation_counts : (6,) the counts each axis saturates at (a ``saturate`` fault's reading).
    """

    def __init__(self, sock: socket.socket, faults: tuple[RdtFault, ...], saturation_counts: np.ndarray):
        self.faults = faults
        self.counts = EmulatorCounts()
        self.client: tuple[str, int] | None = None
        """Where the records go: the address of the last start request."""
        self.rdt_sequence = 0
        """The rdt_sequence of the last record sent in the current stream (0 before its first)."""
        self.last: tuple[int, np.ndarray] | None = None
        """The last record sent: (ft_sequence, (6,) counts before the software bias); None before the first."""
        self._sock = sock
        self._saturation_counts = saturation_counts
        self._sent_index = 0
        self._held: bytes | None = None  # a record held back by a reorder fault

    def start_stream(self, client: tuple[str, int]) -> None:
        """A start request from ``client``: the records go there, numbered from 1 again."""
        self.client = client
        self.rdt_sequence = 0
        self._held = None

    def send(self, t: float, ft_sequence: int, status: int, raw: np.ndarray, bias_counts: np.ndarray) -> None:
        """Send the record of world time ``t`` s: its ft_sequence, status word and (6,) counts ``raw`` before
        the software bias ``bias_counts``, through the faults that hit it."""
        index = self._sent_index
        self._sent_index += 1
        for fault in self.faults:
            if not fault.hits(t, index):
                continue
            if fault.kind == "status":
                status |= fault.status
            elif fault.kind == "saturate":
                raw = np.where(raw < 0, -self._saturation_counts, self._saturation_counts)
                status |= ATI_SATURATION | ATI_ERROR_SUMMARY
            elif fault.kind == "stall" and self.last is not None:
                ft_sequence, raw = self.last[0], self.last[1] + bias_counts
                self.counts.stalled += 1
        self.last = (ft_sequence, raw - bias_counts)
        self.rdt_sequence = (self.rdt_sequence + 1) % 2**32
        record = RECORD.pack(
            self.rdt_sequence, ft_sequence, status, *np.clip(raw - bias_counts, -INT32_MAX - 1, INT32_MAX).tolist()
        )
        self.counts.status += status != 0
        kinds = {f.kind for f in self.faults if f.kind in ("drop", "duplicate", "reorder") and f.hits(t, index)}
        if "drop" in kinds:
            self.counts.dropped += 1
            return
        if "reorder" in kinds and self._held is None:
            self._held = record  # goes out after the next record
            self.counts.reordered += 1
            return
        self._sendto(record)
        if "duplicate" in kinds:
            self._sendto(record)
            self.counts.duplicated += 1
        if self._held is not None:
            held, self._held = self._held, None
            self._sendto(held)

    def _sendto(self, record: bytes) -> None:
        try:
            self._sock.sendto(record, self.client)  # type: ignore[arg-type]  # sent once a client has asked
            self.counts.sent += 1
        except OSError:  # the client went away: a real sensor does not care either
            pass
