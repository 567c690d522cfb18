"""The sample times of a simulated device: each handed out once, in order, on the device's own rate."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["SampleClock"]


class SampleClock:
    """Hands out the sample times of a simulated device once each, in order.

    Sample i is at ``t0_ns + round(i · 1e9 / rate_hz)`` ns.
    """

    def __init__(self, rate_hz: float):
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.t0_ns: int | None = None
        self.next_index = 0

    def start(self, t0_ns: int) -> None:
        """Sample 0 is at ``t0_ns``."""
        self.t0_ns = int(t0_ns)
        self.next_index = 0

    def times(self, seq: np.ndarray) -> np.ndarray:
        """(N,) int64 times of the samples ``seq``, ns."""
        return self.t0_ns + np.rint(seq * (1e9 / self.rate_hz)).astype(np.int64)  # type: ignore[operator]  # after start()

    def end_index(self, until_ns: int) -> int:
        """One past the index of the last sample with time <= ``until_ns`` (at least ``next_index``)."""
        if self.t0_ns is None:
            raise RuntimeError("read() before open()")
        last = math.floor((int(until_ns) - self.t0_ns) * self.rate_hz / 1e9) + 1  # may overshoot by one
        step = 1e9 / self.rate_hz
        while last >= self.next_index and self.t0_ns + round(last * step) > until_ns:  # times(), for one index
            last -= 1
        return max(last + 1, self.next_index)

    def advance(self, until_ns: int) -> range:
        """The indices of every sample not yet taken with time <= ``until_ns`` (taken now; empty when none)."""
        lo = self.next_index
        self.next_index = hi = self.end_index(until_ns)
        return range(lo, hi)

    def take(self, until_ns: int) -> tuple[range, list[int]]:
        """Indices and times of every sample not yet taken with time <= ``until_ns``.

        A live read takes one sample or a few: Python's integers cost less than numpy's per-call
        overhead here, and give :meth:`times`'s values (the same float product, rounded half to even).

        Returns
        -------
        seq : the sample indices (a range, empty when there is none).
        t_ns : their times, ns (Python ints).
        """
        seq = self.advance(until_ns)
        t0_ns, step = self.t0_ns, 1e9 / self.rate_hz
        return seq, [t0_ns + round(i * step) for i in seq]  # type: ignore[operator]  # advance() checked start()
