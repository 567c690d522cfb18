"""Row-wise products of the simulated world that round the same whether a row is computed alone or among many.

The simulated devices compute a scripted world ahead in chunks and a servoed one a sample at a time; a
reading must not depend on which (``prefetch.py``), so every product here is taken row by row.
"""

from __future__ import annotations

import numpy as np

__all__ = ["apply_rows", "cross_rows"]


def apply_rows(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Matrix times vector per row: ``M[i] @ v[i]``.

    M is (N, k, 3) or one (k, 3) matrix; v is (N, 3), one (3,) vector, or
    (N, m, 3) (m vectors per row, each multiplied by that row's M[i]).
    Returns (N, k) or (N, m, k).

    Always a stacked matmul, one small product per row: unlike ``v @ M.T`` (one
    BLAS call for all rows, which rounds a single row differently), each row
    comes out the same whether it is asked for alone or among many, so chunked
    reads give exactly the values of one big read.
    """
    if v.ndim == 3:
        return v @ M.transpose(0, 2, 1)
    return (M @ v[..., None])[..., 0]


_NEXT, _AFTER = [1, 2, 0], [2, 0, 1]


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` for (N, 3) rows: the same products and differences (the same bits), without its
    per-call cost (axis moves and checks, which dominate for a row or two): (a₁b₂ − a₂b₁, a₂b₀ − a₀b₂,
    a₀b₁ − a₁b₀)."""
    return a[:, _NEXT] * b[:, _AFTER] - a[:, _AFTER] * b[:, _NEXT]
