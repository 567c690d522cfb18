"""The play (backlash) operator, compiled: the hysteresis of a sensor's channels.

A play operator of half-width r ≥ 0 follows its input x only once x has moved
more than r away from it::

    h_i = min(max(h_{i−1}, x_i − r), x_i + r)

so ``h − x`` stays within ±r: −r while the input rises (the reading lags its
load on the way up), +r while it falls, and in between after a reversal. It is
the one-operator case of the Prandtl–Ishlinskii (Preisach-type) hysteresis
models. The simulator's sensor (``plugins/simworld/sensor_channels.py``) and the
discrepancy workflow's ``hysteresis`` effect both use it; its pure-Python
``play.py_func`` is the reference the tests compare with.

Compile cost: well under a second the first time, then loaded from ``cache=True`` files.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def play(x: np.ndarray, r: np.ndarray, h0: np.ndarray, out: np.ndarray) -> np.ndarray:
    """Run the play operator over ``x`` in row order; fill ``out`` and return the last output.

    Args:
        x: (n, k) the input, one column per channel (any unit).
        r: (k,) each channel's half-width, same unit, ≥ 0.
        h0: (k,) the output before the first row (its state).
        out: (n, k) the output, written in place.

    Returns:
        (k,) the output after the last row (the state to continue from).
    """
    n, k = x.shape
    h = h0.copy()
    for i in range(n):
        for j in range(k):
            lo = x[i, j] - r[j]
            hi = x[i, j] + r[j]
            v = h[j]
            if v < lo:
                v = lo
            elif v > hi:
                v = hi
            h[j] = v
            out[i, j] = v
    return h


def play_signed(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``x`` (n, k) through play operators of signed half-widths ``r`` (k,), starting relaxed (h = x[0]).

    A negative width gives ``x − (P_|r|[x] − x)``: the mirror image, an output that leads its input. No
    sensor does that; it makes the effect an odd function of r, so that a central difference at r = 0 has
    the derivative −sign(ẋ) of a real hysteresis (with |r| it would be 0 there).
    """
    x = np.ascontiguousarray(x, dtype=float)
    r = np.asarray(r, dtype=float)
    if len(x) == 0:
        return x.copy()
    out = np.empty_like(x)
    play(x, np.abs(r), x[0].copy(), out)
    signed: np.ndarray = x + np.sign(r) * (out - x)
    return signed
