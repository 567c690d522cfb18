"""The noise estimate's step, compiled: the twin of ``noise.py``'s ``adapt_noise`` inside the kalman cascade."""

from __future__ import annotations

import math

from numba import njit

from hapticlab.plugins.estimators.kalman.noise import (
    AUTO_BOUND_FRACTION,
    NOISE_CLIP,
    NOISE_CLIP_MEAN,
    NOISE_PRIOR_SAMPLES,
)


@njit(cache=True, error_model="numpy")
def adapt_noise(r, count, y, A, x, cpc, weight, window, floor):
    """One covariance-matching step on r (3,) in place (``plugins.estimators.kalman.noise.adapt_noise``) for the reading
    y (3,), A (3, 3), at the state x (6,) the sample was predicted from: e = y − A a − b. Returns the count
    after it. A weight of 0 or a non-finite innovation changes nothing."""
    e0 = y[0] - (A[0, 0] * x[0] + A[0, 1] * x[1] + A[0, 2] * x[2]) - x[3]
    e1 = y[1] - (A[1, 0] * x[0] + A[1, 1] * x[1] + A[1, 2] * x[2]) - x[4]
    e2 = y[2] - (A[2, 0] * x[0] + A[2, 1] * x[1] + A[2, 2] * x[2]) - x[5]
    if weight == 0.0 or not (math.isfinite(e0) and math.isfinite(e1) and math.isfinite(e2)):
        return count
    count += weight
    lam = weight / min(count + NOISE_PRIOR_SAMPLES, window)
    clip2 = NOISE_CLIP**2
    for i in range(3):
        e = e0 if i == 0 else (e1 if i == 1 else e2)
        s2 = r[i] + cpc[i]
        sq = min(e**2, clip2 * s2) / NOISE_CLIP_MEAN
        r[i] = max(r[i] + lam * (max(sq - cpc[i], 0.0) - r[i]), floor * floor)
    return count


@njit(cache=True, error_model="numpy")
def _auto_bound2(r, cap):
    """The convergence bound², AUTO_BOUND_FRACTION·noise std (mean variance over the axes), at most cap."""
    bound = min(AUTO_BOUND_FRACTION * math.sqrt((r[0] + r[1] + r[2]) / 3.0), cap)
    return bound * bound
