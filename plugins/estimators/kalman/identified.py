"""Convergence as the motion identifies the parameters: the ``kalman`` estimator's ``convergence = "identified"``,
and its default ``"pose"`` (the second question below alone; the first still followed and reported).

A stage's reading is y_k = A_k a + b + v_k, v_k ~ N(0, diag(r)), C_k = [A_k, I3]. Its filter's P
of the constant a (gravity_force_B, cog_S) holds the bias's random walk, which forgets what the
motion taught within the bias's memory (~1 s with the default drift): on a slow motion P of a
stays wide long after the motion has determined a. Two questions answer "is it known" instead:

* **identified**: how well the accepted samples determine a with the bias held constant, from
  their information Λ = Λ₀ + Σ C_kᵀ R⁻¹ C_k (6×6, [a, b]); a's covariance is the top-left
  block of Λ⁻¹ (Λ₀ from the filter's P whenever the estimator re-opens what it knows);
* **known here**: the reading's variance at the current pose, diag(C_k P C_kᵀ) with the
  filter's P: the constant and the bias are each wide but strongly anti-correlated, and at the
  poses the robot is at their sum is known.

A constant's axis the motion has not told apart from the bias at all is **not identifiable from the
motion so far** (:func:`unidentified_axes`): a still tool leaves every axis of a there (the data fix
a + b only), a turn about one axis leaves a's component along it (it maps to the same sensor
direction at every pose, like the bias); the estimator reports no number for it.

The numpy reference, one sample at a time; the compiled twin is in ``plugins.estimators.kalman.cascade_kernel``.
Shapes: A (3, 3), P (6, 6), info (6, 6), r (3,).
"""

from __future__ import annotations

import numpy as np

from hapticlab.plugins.estimators.kalman.stage import I3


def predicted_var(P: np.ndarray, A: np.ndarray) -> np.ndarray:
    """(3,) diag(C P Cᵀ), C = [A, I3]: the variance of the predicted reading per axis, units²."""
    C = np.hstack([A, I3])
    return np.einsum("ij,jl,il->i", C, P[:6, :6], C)


def add_information(info: np.ndarray, A: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(6, 6) Λ + Cᵀ diag(1/r) C, C = [A, I3]: one accepted sample's information added."""
    C = np.hstack([A, I3])
    return info + (C.T / r) @ C


def constant_var(info: np.ndarray) -> np.ndarray:
    """(3,) the variance of the constant a per axis, diag((Λ⁻¹)[:3, :3]), units² (inf if Λ is singular)."""
    try:
        return np.linalg.inv(info).diagonal()[:3].copy()
    except np.linalg.LinAlgError:
        return np.full(3, np.inf)


IDENTIFIABLE_FRACTION = 0.5
"""An axis of a constant is identified by the motion so far once its std is below this fraction of its
prior's. Measured by what the data cannot do: with a + b fixed and both at the prior p, a's std is p/√2
(0.71 p); any motion that separates them brings it towards the noise's scale (~1e-3 p)."""


def unidentified_axes(std, prior_std: float) -> tuple[int, ...]:
    """The axes (0, 1, 2) of a constant whose std (3 floats) is not below ``IDENTIFIABLE_FRACTION`` of its
    prior's (same units): those the motion so far has not identified. (Plain floats: it runs every tick.)"""
    bound = IDENTIFIABLE_FRACTION * prior_std
    return tuple(i for i, s in enumerate(std) if not s < bound)


IDENTIFIED_FRACTION = 0.05
"""An axis is clearly identified below this fraction of its prior's std (1 N of gravity, 25 mm of the centre
of mass with the defaults): :func:`decided`."""


def decided(std, prior_std: float) -> bool:
    """Every axis of std (3 floats) clearly identified (below ``IDENTIFIED_FRACTION`` of the prior's) or
    clearly not (not below ``IDENTIFIABLE_FRACTION``): none is on its way from one to the other."""
    low, high = IDENTIFIED_FRACTION * prior_std, IDENTIFIABLE_FRACTION * prior_std
    return all(s < low or not s < high for s in std)
