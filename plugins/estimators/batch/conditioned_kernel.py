"""Which of the ``batch`` fit's normal matrices are certainly conditioned, compiled: its flags without an SVD each.

The reference (``kernel = "numpy"``) flags a fit converged where the reciprocal condition number of its
normal matrix scaled to unit diagonal, ``s[-1] / s[0]`` from LAPACK's gesdd, is at least ``min_rcond``: a
6×6 SVD per sample and fit, a third of the estimator's time. Only the flag is used, so this kernel decides
it where a Cholesky factorisation proves it and leaves the rest (``UNDECIDED``) to the very same gesdd.

The proof. M (the scaled matrix) is symmetric (up to rounding, within ``SLACK``), so its singular values
are |eigenvalues|; its entries are at most 1 in magnitude (unit diagonal, Cauchy-Schwarz), so ‖M‖₂ ≤ u,
its largest absolute row sum (≤ 6).
gesdd is backward stable: each singular value it returns is within p·eps·‖M‖₂ of the exact one (p a
small polynomial in n = 6; ``SLACK`` = 1e-12 ≫ 100·eps·6). If the factorisation of M − a·I succeeds
with every pivot above ``SLACK`` for a = min_rcond·(1 + 1e-9)·(u + SLACK) + 3·SLACK, then λ_min(M) > a −
SLACK (the factorisation's own rounding is below 1e-13 at these magnitudes), so gesdd's s[-1] exceeds
min_rcond·(1 + 1e-9)·gesdd's s[0]: the reference's flag is up. A factorisation that fails proves
nothing: such samples (the first of a tour, a weakly excited one) are undecided.

``solve`` is the other use of the proof (``solver = "cholesky"``): where the scaled matrix is proved
positive definite, the fit is solved by its Cholesky factor (equilibrated: x = D⁻¹ M⁻¹ D⁻¹ Cᵀy) instead of
numpy's pinv (an SVD each): the same least-squares solution in exact arithmetic, not the same bits (the
difference is bounded by cond(M)·eps relative, cond(M) ≤ 6/min_rcond where proved; the tests measure it).

Compiled the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

UP = 1
"""``certain`` code: gesdd's reciprocal condition number is certainly at least ``min_rcond``."""
UNDECIDED = 0
"""``certain`` code: the factorisation did not prove it; the caller asks gesdd."""
SLACK = 1e-12
"""Absolute bound (well above) on gesdd's and the factorisation's rounding at the scaled matrix's magnitudes."""


@njit(cache=True)
def cholesky_shifted(M: np.ndarray, shift: float, L: np.ndarray) -> bool:
    """Write the Cholesky factor of M − shift·I into the lower triangle of ``L``; False (``L`` unfinished) at
    the first pivot not above ``SLACK``.

    Args:
        M: (n, n) symmetric (its lower triangle is read). shift: subtracted from the diagonal (0: M itself).
        L: (n, n), written.
    """
    n = M.shape[0]
    for j in range(n):
        d = M[j, j] - shift
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not d > SLACK:
            return False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            v = M[i, j]
            for p in range(j):
                v -= L[i, p] * L[j, p]
            L[i, j] = v / L[j, j]
    return True


@njit(cache=True)
def certain(scaled: np.ndarray, min_rcond: float, out: np.ndarray) -> int:
    """Write ``UP`` or ``UNDECIDED`` for each matrix into ``out``; return how many are undecided.

    Args:
        scaled: (m, 6, 6) normal matrices scaled to unit diagonal (symmetric).
        min_rcond: the reciprocal condition number a converged fit has at least, in [1e-12, 1].
        out: (m,) int8, written.
    """
    n = scaled.shape[1]
    L = np.empty((n, n))
    undecided = 0
    for k in range(scaled.shape[0]):
        M = scaled[k]
        u = 0.0
        for i in range(n):
            row = 0.0
            for j in range(n):
                row += abs(M[i, j])
            u = max(u, row)
        a = min_rcond * (1.0 + 1e-9) * (u + SLACK) + 3.0 * SLACK
        ok = math.isfinite(u) and cholesky_shifted(M, a, L)
        out[k] = UP if ok else UNDECIDED
        undecided += 0 if ok else 1
    return undecided


@njit(cache=True)
def solve(scaled: np.ndarray, d: np.ndarray, Cty: np.ndarray, code: np.ndarray, X: np.ndarray) -> None:
    """X[k] = (CᵀC)⁻¹ Cᵀy by the Cholesky factor of scaled[k], for each k whose ``code`` is ``UP``.

    Args:
        scaled: (m, 6, 6) CᵀC scaled to unit diagonal, D⁻¹ CᵀC D⁻¹. d: (m, 6) the diagonal of D.
        Cty: (m, 6) Cᵀy. code: (m,) from ``certain``. X: (m, 6), written where ``code`` is ``UP``.
    """
    n = scaled.shape[1]
    L = np.empty((n, n))
    z = np.empty(n)
    for k in range(scaled.shape[0]):
        if code[k] != UP:
            continue
        cholesky_shifted(scaled[k], 0.0, L)  # proved positive definite (UP): every pivot is above SLACK
        for i in range(n):  # L z = D⁻¹ Cᵀy
            v = Cty[k, i] / d[k, i]
            for p in range(i):
                v -= L[i, p] * z[p]
            z[i] = v / L[i, i]
        for i in range(n - 1, -1, -1):  # Lᵀ w = z, x = D⁻¹ w
            v = z[i]
            for p in range(i + 1, n):
                v -= L[p, i] * z[p]
            z[i] = v / L[i, i]
            X[k, i] = z[i] / d[k, i]


def warm_up() -> None:
    """Compile (or load from the cache) ``certain`` and ``solve`` before the first block."""
    scaled, code = np.tile(np.eye(6), (2, 1, 1)), np.zeros(2, dtype=np.int8)
    certain(scaled, 1e-4, code)
    solve(scaled, np.ones((2, 6)), np.ones((2, 6)), code, np.zeros((2, 6)))
