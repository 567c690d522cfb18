"""The simulated world's random streams: white noise and random-walk drift, pure functions of (seed, time).

Independent streams, all from ``numpy.random.SeedSequence(seed)`` by spawn key:
0 white noise, 1 random-walk bias drift, 2 motion waypoints
(``motion/random_tour.py``). Every random quantity is a pure function of
(seed, time), so a stream is identical whether it is asked for in one call or
in chunks, in any order, any number of times:

* **White noise** is counter-based: the Gaussian for (axis, sample) is computed
  from a hash (SplitMix64) of the noise-stream key, the sample time in integer
  nanoseconds and the axis, then a Box–Muller transform. (A sequential
  generator would tie the noise of a sample to how many samples were drawn
  before it, by whom.)
* **Random-walk drift** is a Brownian path on a fixed 10 ms grid, drawn block by
  block with ``default_rng`` (block b from spawn key (1, b)) and linearly
  interpolated between grid points.
"""

from __future__ import annotations

import functools
import threading

import numpy as np

__all__ = ["DRIFT_STREAM", "NOISE_STREAM", "GrowingPath", "RandomWalk", "gaussian_noise"]

NOISE_STREAM = 0
"""SeedSequence spawn key of the white-noise stream."""

DRIFT_STREAM = 1
"""SeedSequence spawn key of the random-walk drift stream."""

_U64 = np.uint64
_CHANNEL_STEP = 0xD1B54A32D192ED03  # an odd 64-bit constant separating the channels' counters
_GOLDEN_GAMMA, _MIX_1, _MIX_2 = _U64(0x9E3779B97F4A7C15), _U64(0xBF58476D1CE4E5B9), _U64(0x94D049BB133111EB)
_SHIFT_11, _SHIFT_27, _SHIFT_30, _SHIFT_31 = _U64(11), _U64(27), _U64(30), _U64(31)


def _times(t: float | np.ndarray) -> np.ndarray:
    """Times as a 1-D float array (a scalar becomes one element)."""
    return np.atleast_1d(np.asarray(t, dtype=float)).ravel()


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """The SplitMix64 finaliser: a bijective, well-mixing hash of uint64 arrays."""
    x = x + _GOLDEN_GAMMA
    x = (x ^ (x >> _SHIFT_30)) * _MIX_1
    x = (x ^ (x >> _SHIFT_27)) * _MIX_2
    return x ^ (x >> _SHIFT_31)


@functools.cache
def _channel_offsets(channels: int) -> np.ndarray:
    """(channels,) uint64 counter offsets: channel c adds ``(c + 1) · _CHANNEL_STEP`` (mod 2⁶⁴)."""
    # Python ints first: no numpy scalar overflow
    offsets = np.array([((c + 1) * _CHANNEL_STEP) % 2**64 for c in range(channels)], dtype=np.uint64)
    offsets.setflags(write=False)
    return offsets


def gaussian_noise(key: int, t_ns: np.ndarray, channels: int) -> np.ndarray:
    """Standard-normal numbers that depend only on (key, time, channel).

    Parameters
    ----------
    key : 64-bit stream key (from the world's SeedSequence).
    t_ns : (N,) int64 sample times, ns.
    channels : number of independent values per sample (even).

    Returns
    -------
    (N, channels) float array, independent N(0, 1) across samples and channels.
    """
    counter = np.ascontiguousarray(t_ns, dtype=np.int64).view(np.uint64)
    base = _splitmix64(counter ^ _U64(key))
    # all channels at once: a different odd-constant offset per channel, then
    # Box–Muller on the pairs (channel 2i, channel 2i + 1)
    bits = _splitmix64(base[:, None] + _channel_offsets(channels))
    uniform = ((bits >> _SHIFT_11).astype(float) + 0.5) * 2.0**-53  # in (0, 1)
    u1, u2 = uniform[:, 0::2], uniform[:, 1::2]
    radius = np.sqrt(-2.0 * np.log(u1))
    angle = 2.0 * np.pi * u2
    out = np.empty((len(counter), channels))
    out[:, 0::2] = radius * np.cos(angle)
    out[:, 1::2] = radius * np.sin(angle)
    return out


class GrowingPath:
    """A path on a time grid that only grows: extended under a lock by :meth:`_more` as later points are
    asked for, and read without one (so what it holds at a point never depends on what was asked before)."""

    def __init__(self, start: np.ndarray):
        self._path = start
        self._lock = threading.Lock()

    def _ensure(self, points: int) -> None:
        if len(self._path) >= points:  # the usual case: no lock needed (the path only grows)
            return
        with self._lock:
            while len(self._path) < points:
                self._path = np.concatenate([self._path, self._more(points)])

    def _more(self, points: int) -> np.ndarray:
        """The rows after the last one held (towards ``points``)."""
        raise NotImplementedError


class RandomWalk(GrowingPath):
    """Standard Brownian paths W(t) for several channels (W(0) = 0, Var W(t) = t).

    Sampled on a grid of ``grid_s`` and linearly interpolated in between; before
    t = 0 the path is 0. The grid is drawn block by block (``block`` steps per
    block), block b from ``default_rng(SeedSequence(seed, spawn_key=(stream, b)))``,
    and cached, so W at a time never depends on the times asked for before.
    """

    def __init__(
        self, seed: int, stream: int = DRIFT_STREAM, channels: int = 6, grid_s: float = 0.01, block: int = 4096
    ):
        super().__init__(np.zeros((1, channels)))  # W at grid points 0, 1, ...
        self.seed, self.stream, self.channels = seed, stream, channels
        self.grid_s, self.block = grid_s, block

    def _more(self, points: int) -> np.ndarray:
        b = (len(self._path) - 1) // self.block
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(self.stream, b)))
        steps = rng.standard_normal((self.block, self.channels)) * np.sqrt(self.grid_s)
        return self._path[-1] + np.cumsum(steps, axis=0)

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """(N, channels) W at times ``t`` (s)."""
        x = np.maximum(_times(t), 0.0) / self.grid_s
        k = np.floor(x).astype(np.int64)
        self._ensure(int(k.max(initial=0)) + 2)
        frac = (x - k)[:, None]
        return self._path.take(k, axis=0) * (1.0 - frac) + self._path.take(k + 1, axis=0) * frac
