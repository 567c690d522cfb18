"""A networked device's sample counter mapped onto the session's monotonic clock (the Net F/T's, the UR's).

A device stamps each sample with its own counter (the Net F/T's ``ft_sequence``,
the UR controller's ``timestamp``); stamping a sample by its receipt instead
would add the network's and the scheduler's jitter to every sample time.
:class:`DeviceClock` keeps the device's own spacing and follows the fastest
packets, for every device plugin that has such a counter.
"""

from __future__ import annotations

import numpy as np


class DeviceClock:
    """Maps a device's sample counter onto the session's monotonic clock, ns.

    The counter ``k`` runs at ``rate_hz`` on the device's crystal; a sample's
    receive time is its device time plus a latency that is never negative and
    often near its minimum. So the offset between the two clocks is the lower
    envelope of ``received_ns − k·1e9/rate_hz``: it follows every new minimum at
    once, and may rise at ``slew_ppm`` of the elapsed device time (the device's
    crystal running fast against the host's, ≤ ~100 ppm for a crystal). A
    sample's time is ``k·1e9/rate_hz + offset``: never later than its receipt,
    spaced by the device's own clock, and non-decreasing (a lower envelope that
    drops by more than one sample period is held to the previous time + 1 ns).

    Parameters
    ----------
    rate_hz : the counter's rate, Hz.
    slew_ppm : fastest rise of the offset, parts per million of device time.
    """

    def __init__(self, rate_hz: float = 7000.0, slew_ppm: float = 200.0):
        self.period_ns = 1e9 / rate_hz
        self.slew = slew_ppm * 1e-6
        self.offset_ns: float | None = None
        self.last_k: int | None = None
        self.last_t_ns: int | None = None

    def reset(self) -> None:
        """Forget the mapping (the device restarted its counter)."""
        self.offset_ns = self.last_k = self.last_t_ns = None

    def stamp(self, k: int, received_ns: int) -> int:
        """The session time of device sample ``k`` (unwrapped counter) received at ``received_ns``, ns."""
        device_ns = k * self.period_ns
        seen = received_ns - device_ns
        if self.offset_ns is None:
            self.offset_ns = seen
        else:
            self.offset_ns = min(seen, self.offset_ns + self.slew * (k - self.last_k) * self.period_ns)  # type: ignore[operator]  # last_k is set with offset_ns
        self.last_k = k
        t_ns = round(device_ns + self.offset_ns)
        if self.last_t_ns is not None and t_ns <= self.last_t_ns:
            t_ns = self.last_t_ns + 1
        self.last_t_ns = t_ns
        return t_ns

    def stamp_many(self, k: np.ndarray, received_ns: int | np.ndarray) -> np.ndarray:
        """:meth:`stamp` of many samples at once (unwrapped counters ``k`` in order), ns.

        The envelope's recursion ``o_i = min(seen_i, o_(i-1) + c·(k_i − k_(i-1)))`` is
        ``c·k_i + cummin(seen_j − c·k_j)``, and "at least the previous time + 1 ns" is
        ``i + cummax(t_j − j)``: two accumulates instead of a Python loop.
        """
        c = self.slew * self.period_ns
        base = received_ns - k * (self.period_ns + c)  # seen − c·k
        np.minimum.accumulate(base, out=base)
        if self.offset_ns is not None:
            np.minimum(base, self.offset_ns - c * self.last_k, out=base)  # type: ignore[operator]  # set with offset_ns
        self.offset_ns, self.last_k = float(base[-1] + c * k[-1]), int(k[-1])
        step = np.arange(len(k))
        u = np.rint(base + k * (self.period_ns + c)).astype(np.int64) - step  # t − i
        if self.last_t_ns is not None:
            np.maximum(u, self.last_t_ns + 1, out=u)
        t_ns = np.maximum.accumulate(u) + step
        self.last_t_ns = int(t_ns[-1])
        return t_ns
