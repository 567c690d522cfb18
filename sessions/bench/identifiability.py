"""How early can any estimator know the tool's weight from a recording's motion?

The most information the motion gives about the force stage's parameters, x =
[gravity_force_B, bias_force_S]: a constant bias, a known noise σ and every row
used (least squares over rows 1..k, C_k = [R_EB, I3]). No estimator can honestly
call gravity identified before this fit's std falls under its bound: a drifting
bias, an estimated σ or rows refused as contact can only make it later.
``bench/identifiability.py`` prints it for a folder of recordings.
"""

from __future__ import annotations

import numpy as np


def gravity_std_over_rows(R_EB: np.ndarray) -> np.ndarray:
    """(n,) largest std of gravity_force_B, in units of σ, after rows 1..k (inf while not determined)."""
    n = len(R_EB)
    C = np.concatenate([R_EB, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (n, 3, 6)
    info = np.cumsum(np.einsum("kij,kil->kjl", C, C), axis=0)  # Σ CᵀC, (n, 6, 6)
    out = np.full(n, np.inf)
    determined = np.linalg.cond(info) < 1e12
    if determined.any():
        out[determined] = np.sqrt(np.linalg.inv(info[determined])[:, :3, :3].diagonal(axis1=1, axis2=2).max(axis=1))
    return out


def first_below(std: np.ndarray, bound: float) -> int | None:
    """The first row whose std is below ``bound`` (None if none is)."""
    below = np.flatnonzero(std < bound)
    return int(below[0]) if len(below) else None
