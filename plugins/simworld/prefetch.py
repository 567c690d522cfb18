"""Simulated devices compute their readings a few tens of milliseconds ahead, in one vectorised call.

The simulated world is a function of time (its noise is keyed on each sample's
stamp, its random walks on a fixed grid), so the reading of sample i does not
depend on which samples are computed with it. Computing one sample per loop
tick spends nearly all of the time in numpy's per-call overhead; computing
``PREFETCH_S`` of samples at once and handing out slices gives the same numbers
for a fraction of the cost (``hapticlab bench loop``: sensor and kinematics
reads). A world whose robot follows live targets (``SimWorld.live``) is only
known up to now: its devices pass ``ahead_s = 0`` for the physics and compute
what is asked, and compute ahead only what depends on the time alone (the
sensor channels' bias and noise, the encoders' jitter, the robot wrench's noise).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

PREFETCH_S = 1.0
"""How far ahead the simulated devices compute, s, up to ``PREFETCH_MAX_SAMPLES`` (so 400 samples at 1 kHz,
at 500 Hz and at 7 kHz alike). A chunk's first numpy calls run cold (the loop has not made them for a
while), a cost paid once per chunk, so fewer, larger chunks cost less per sample."""
PREFETCH_MAX_SAMPLES = 400
"""The most samples one chunk computes (a 7 kHz sensor's 57 ms): small enough for a paced session's loop
to compute while it would sleep, ten ticks ahead (``PreparesAhead``, ``loop.PREPARE_AHEAD_TICKS``)."""


class Prefetch:
    """Arrays computed for a run of consecutive sample indices ahead of need, handed out as read-only slices.

    Args:
        compute: ``compute(seq)`` → dict of arrays whose first axis runs along ``seq`` ((N,) int64 indices).
        rate_hz: the device's sample rate, Hz (sets the chunk: ``ahead_s`` of samples, at least one and at
            most ``PREFETCH_MAX_SAMPLES``).
        ahead_s: how far ahead to compute, s (0: only the samples asked for).
    """

    def __init__(
        self, compute: Callable[[np.ndarray], dict[str, np.ndarray]], rate_hz: float, ahead_s: float = PREFETCH_S
    ):
        self.compute = compute
        self.chunk = min(max(round(ahead_s * rate_hz), 1), PREFETCH_MAX_SAMPLES)
        self.first = 0  # index of the cache's first sample
        self.cache: dict[str, np.ndarray] = {}
        self.size = 0

    def reset(self) -> None:
        """Forget the cache (the device was reopened: its clock starts again)."""
        self.cache, self.size = {}, 0

    def prepare(self, lo: int, hi: int) -> None:
        """Make sure the indices ``lo`` ≤ i < ``hi`` are computed (a chunk from ``lo`` on if they are not).

        Nothing to do when computing ahead is off (``ahead_s = 0``: only what is asked for is known).
        """
        if self.chunk > 1 and hi > lo:
            self._cover(lo, hi)

    def _cover(self, lo: int, hi: int) -> None:
        if not (self.first <= lo and hi <= self.first + self.size):
            n = max(self.chunk, hi - lo)
            self.cache = self.compute(np.arange(lo, lo + n, dtype=np.int64))
            for array in self.cache.values():
                array.setflags(write=False)
            self.first, self.size = lo, n

    def take(self, lo: int, hi: int) -> dict[str, np.ndarray]:
        """The arrays for the indices ``lo`` ≤ i < ``hi``, as read-only views."""
        self._cover(lo, hi)
        a, b = lo - self.first, hi - self.first
        return {key: array[a:b] for key, array in self.cache.items()}

    def copies(self, lo: int, hi: int) -> list[np.ndarray]:
        """The arrays for the indices ``lo`` ≤ i < ``hi`` as copies of their own (writable, contiguous), in the
        order ``compute`` returned them."""
        self._cover(lo, hi)
        a, b = lo - self.first, hi - self.first
        return [array[a:b].copy() for array in self.cache.values()]
