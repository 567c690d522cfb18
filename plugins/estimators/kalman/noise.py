"""The sensor's noise estimated as the filter runs: covariance matching, one sample at a time.

The ``kalman`` estimator's ``noise = "auto"`` (the numpy reference; the compiled twin is
``plugins.estimators.kalman.cascade_kernel``). For a stage whose reading is y_k = C_k x + v_k, v_k ~ N(0, R), the
innovation at the state the sample was predicted from, e_k = y_k − C_k x⁻, has variance
R + C_k P C_kᵀ, so per axis

    R ← R + λ_k (max(e_k² − (C_k P C_kᵀ)ᵢᵢ, 0) − R)

is a running estimate of R. λ_k = w_k / min(n_k + n₀, N): the start value counts as
``NOISE_PRIOR_SAMPLES`` (n₀) samples, so a quiet start cannot collapse R before the robot
moves; the mean then grows over N samples (the larger of ``NOISE_WINDOW`` and
``NOISE_WINDOW_S`` at the sensor's rate) and forgets exponentially after. Each e² is clipped at
``NOISE_CLIP`` standard deviations of its predicted distribution (a contact the gate let
through, or an outlier, moves R by a bounded amount), and the clipped mean's bias corrected
(``NOISE_CLIP_MEAN``: E[min(z², 9)] of a standard normal z). A sample the gate refused counts
with weight ``NOISE_REFUSED_WEIGHT`` before the force stage first converged (so a noise
estimate that started too small for this sensor, whose every sample the gate refuses, still
grows) and not at all after (a refusal is then a contact; a long one must not inflate R).
R never falls below ``NOISE_FLOOR``².

Symbols and shapes: e (3,) innovation; cpc (3,) diag(C P Cᵀ) (the torque stage adds the force
noise it carries through the centre of gravity); r (3,) R's diagonal, units²; n the weight seen.
"""

from __future__ import annotations

import numpy as np

NOISE_AUTO_START_FORCE = 0.5
"""N: the force noise an ``auto`` estimate starts from (above any sensor's of this class: a start
too large only delays convergence; one too small refuses every sample)."""
NOISE_AUTO_START_TORQUE = 0.05
"""N·m: the same for the torque."""
NOISE_WINDOW = 1000
"""Samples: the least the running mean averages over (it grows to this window, then forgets
exponentially with it)."""
NOISE_PRIOR_SAMPLES = 50
"""The start value's weight, in samples."""
NOISE_WINDOW_S = 10.0
"""s: the running mean's window at the sensor's rate (when that is more than NOISE_WINDOW samples)."""
NOISE_CLIP = 3.0
"""Each squared innovation is clipped at this many predicted standard deviations."""
NOISE_CLIP_MEAN = 0.9950
"""E[min(z², NOISE_CLIP²)] for a standard normal z: the clipped mean's correction."""
NOISE_REFUSED_WEIGHT = 0.1
"""The weight of a refused sample before the force stage first converged."""
NOISE_FLOOR = (1e-3, 1e-4)
"""(N, N·m): the least noise std the estimate may reach (duplicated rows must not make R zero)."""
AUTO_BOUND_FRACTION = 0.5
"""With the noise estimated and no bound given, a stage converges when its parameters are known to
this fraction of the estimated noise std (the mean variance over the axes). Looser than the
configured defaults (a sixth of a Gamma-class sensor's noise): a sensor of unknown noise is usually one whose
residual is mostly model error, and there a sixth is not reached within a short recording (``bench real``
measures it, docs/estimators.md)."""


def window_samples(dt: float) -> int:
    """The running mean's window, in samples, for a sensor sampled every ``dt`` s (> 0)."""
    return max(NOISE_WINDOW, int(NOISE_WINDOW_S / dt))


def adapt_noise(
    r: np.ndarray, count: float, e: np.ndarray, cpc: np.ndarray, weight: float, window: int, floor: float
) -> tuple[np.ndarray, float]:
    """One sample's covariance-matching step.

    Args:
        r: (3,) noise variance per axis before the sample, units².
        count: the weight of the samples seen so far.
        e: (3,) the innovation at the state the sample was predicted from, units.
        cpc: (3,) diag(C P Cᵀ) (plus any noise the stage carries from another), units².
        weight: 1 for an accepted sample, NOISE_REFUSED_WEIGHT or 0 for a refused one.
        window: the running mean's window, samples.
        floor: the least std, units.

    Returns:
        (r after the sample (3,), count after it). A sample of weight 0 or with a non-finite
        innovation changes nothing.
    """
    if weight == 0.0 or not np.isfinite(e).all():
        return r, count
    count += weight
    lam = weight / min(count + NOISE_PRIOR_SAMPLES, window)
    s2 = r + cpc
    e2 = np.minimum(e**2, NOISE_CLIP**2 * s2) / NOISE_CLIP_MEAN
    r = r + lam * (np.maximum(e2 - cpc, 0.0) - r)
    return np.maximum(r, floor**2), count
