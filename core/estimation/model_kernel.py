"""The estimators' sample guard, compiled: is every sample of a block one the model may see?

The compiled twin of ``core.estimation.model.all_plausible``'s screen (``refusal_codes``
stays the reference): each sample's force and torque components within the
bounds, its R_EB a rotation (‖R Rᵀ − I‖²_F ≤ tolerance², det R > 0); a NaN
fails every comparison, an overflow gives inf and fails too. Every estimator
runs it on every block (the primary and each shadow), so it is one compiled
pass instead of a dozen numpy calls.

Compiled the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def all_plausible(
    force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray, max_force: float, max_torque: float, tolerance: float
) -> bool:
    """True when no sample of the block would be refused.

    Args:
        force_S, torque_S: (m, 3) the readings, N and N·m.
        R_EB: (m, 3, 3) the orientations.
        max_force, max_torque: the bounds on each component's magnitude, N and N·m.
        tolerance: the largest ‖R Rᵀ − I‖_F of a rotation.
    """
    for s in range(force_S.shape[0]):
        for k in range(3):
            if not (abs(force_S[s, k]) <= max_force and abs(torque_S[s, k]) <= max_torque):
                return False
        a, b, c = R_EB[s, 0, 0], R_EB[s, 0, 1], R_EB[s, 0, 2]
        d, e, g = R_EB[s, 1, 0], R_EB[s, 1, 1], R_EB[s, 1, 2]
        h, i, j = R_EB[s, 2, 0], R_EB[s, 2, 1], R_EB[s, 2, 2]
        n0, n1, n2 = a * a + b * b + c * c - 1.0, d * d + e * e + g * g - 1.0, h * h + i * i + j * j - 1.0
        o01, o02, o12 = a * d + b * e + c * g, a * h + b * i + c * j, d * h + e * i + g * j
        frobenius2 = n0 * n0 + n1 * n1 + n2 * n2 + 2.0 * (o01 * o01 + o02 * o02 + o12 * o12)
        det = a * (e * j - g * i) - b * (d * j - g * h) + c * (d * i - e * h)
        if not (frobenius2 <= tolerance * tolerance and det > 0.0):
            return False
    return True


def warm_up() -> None:
    """Compile (or load from the cache) ``all_plausible`` before the first live tick."""
    all_plausible(np.zeros((2, 3)), np.zeros((2, 3)), np.tile(np.eye(3), (2, 1, 1)), 1.0, 1.0, 1e-6)
