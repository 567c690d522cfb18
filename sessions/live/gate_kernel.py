"""The live loop's screen of each aligned block, compiled: which samples an estimator may see, and why not.

The compiled twin of ``AlignedSamples.usable`` (orientation not stale, status
``STATUS_OK``, wrench, R_EB and position finite), ``sessions.live.screen.implausible``
(a good-status reading beyond the sensor's range: it would have saturated) and
``screen.data_reason``'s order of causes, in one pass over the block: at one
sample per tick the numpy versions' dozen calls cost an order of magnitude more
than this one pass (docs/safety.md, "Overruns"). The numpy code stays the
reference the tests compare with.

Compile cost: well under a second the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

BEYOND, STALE, BAD_STATUS, NON_FINITE = 1, 2, 4, 8
"""Bits of :func:`screen_block`'s result: what some sample of the block had (0: every sample usable)."""


@njit(cache=True)
def screen_block(force_S, torque_S, R_EB, p_BoEo_B, stale, status, range_force_S, range_torque_S, usable, beyond):
    """Fill ``usable`` and ``beyond`` ((N,) bool) in place; return the bits of what was wrong in the block.

    Args:
        force_S, torque_S: (N, 3) the readings, N and N·m.
        R_EB: (N, 3, 3) the orientations; p_BoEo_B: (N, 3) positions, m, or (0, 3) when the stream has none.
        stale: (N,) bool; status: (N,) int64 status words (0 good).
        range_force_S, range_torque_S: (3,) the sensor's range (N, N·m), or (0,) when it reports none.
        usable, beyond: (N,) bool outputs.
    """
    n = force_S.shape[0]
    has_range = range_force_S.shape[0] == 3
    has_p = p_BoEo_B.shape[0] == n and n > 0
    bits = 0
    for i in range(n):
        finite = True
        out = False
        for k in range(3):
            f, t = force_S[i, k], torque_S[i, k]
            if not (math.isfinite(f) and math.isfinite(t)):
                finite = False
            if has_range and (abs(f) > range_force_S[k] or abs(t) > range_torque_S[k]):  # NaN: False, as numpy
                out = True
            for j in range(3):
                if not math.isfinite(R_EB[i, k, j]):
                    finite = False
            if has_p and not math.isfinite(p_BoEo_B[i, k]):
                finite = False
        good = status[i] == 0
        beyond[i] = out and good
        usable[i] = finite and good and not stale[i] and not beyond[i]
        if beyond[i]:
            bits |= BEYOND
        if stale[i]:
            bits |= STALE
        if not good:
            bits |= BAD_STATUS
        if not finite:
            bits |= NON_FINITE
    return bits


def warm_up() -> None:
    """Compile (or load from the cache) ``screen_block`` before the first live tick."""
    n = 2
    screen_block(
        np.zeros((n, 3)),
        np.zeros((n, 3)),
        np.tile(np.eye(3), (n, 1, 1)),
        np.zeros((0, 3)),
        np.zeros(n, dtype=np.bool_),
        np.zeros(n, dtype=np.int64),
        np.ones(3),
        np.ones(3),
        np.empty(n, dtype=np.bool_),
        np.empty(n, dtype=np.bool_),
    )
