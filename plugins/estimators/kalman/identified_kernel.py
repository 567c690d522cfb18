"""What the motion has identified, compiled: the twin of ``identified.py`` inside the kalman cascade."""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, error_model="numpy")
def predicted_var(P, A, out):
    """out (3,) = diag(C P Cᵀ), C = [A, I3] (``plugins.estimators.kalman.identified.predicted_var``)."""
    for i in range(3):
        a0, a1, a2 = A[i, 0], A[i, 1], A[i, 2]
        quad = (
            a0 * (P[0, 0] * a0 + P[0, 1] * a1 + P[0, 2] * a2)
            + a1 * (P[1, 0] * a0 + P[1, 1] * a1 + P[1, 2] * a2)
            + a2 * (P[2, 0] * a0 + P[2, 1] * a1 + P[2, 2] * a2)
        )
        out[i] = quad + 2.0 * (a0 * P[0, 3 + i] + a1 * P[1, 3 + i] + a2 * P[2, 3 + i]) + P[3 + i, 3 + i]


@njit(cache=True, error_model="numpy")
def add_information(info, A, r):
    """info (6, 6) += Cᵀ diag(1/r) C, C = [A, I3], in place
    (``plugins.estimators.kalman.identified.add_information``)."""
    for j in range(6):
        for l in range(j, 6):
            s = 0.0
            for i in range(3):
                cj = A[i, j] if j < 3 else (1.0 if i == j - 3 else 0.0)
                cl = A[i, l] if l < 3 else (1.0 if i == l - 3 else 0.0)
                s += cj * cl / r[i]
            info[j, l] += s
            if l != j:
                info[l, j] = info[j, l]


@njit(cache=True, error_model="numpy")
def constant_var3(info, L):
    """diag((Λ⁻¹)[:3, :3]) (``plugins.estimators.kalman.identified.constant_var``) as three floats, inf if Λ is
    not positive definite.

    Cholesky of Λ reordered as [b, a] (L (6, 6) scratch): the trailing 3×3 factor T has T Tᵀ = the Schur
    complement Λ_aa − Λ_ab Λ_bb⁻¹ Λ_ba = ((Λ⁻¹)_aa)⁻¹, so diag((Λ⁻¹)_aa) are the squared column norms
    of T⁻¹."""
    for i in range(6):
        pi = (i + 3) % 6
        for j in range(i + 1):
            s = info[pi, (j + 3) % 6]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return math.inf, math.inf, math.inf
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    t00, t10, t11, t20, t21, t22 = L[3, 3], L[4, 3], L[4, 4], L[5, 3], L[5, 4], L[5, 5]
    v00, v11, v22 = 1.0 / t00, 1.0 / t11, 1.0 / t22
    v10 = -t10 * v00 / t11
    v21 = -t21 * v11 / t22
    v20 = -(t20 * v00 + t21 * v10) / t22
    return v00 * v00 + v10 * v10 + v20 * v20, v11 * v11 + v21 * v21, v22 * v22


@njit(cache=True, error_model="numpy")
def constant_var_max(info, L):
    """The largest of :func:`constant_var3` (inf if Λ is not positive definite)."""
    a, b, c = constant_var3(info, L)
    return max(a, b, c)
