"""The torque stage's bias about the measured force: what it estimates, and the physical bias it reports.

The torque stage regresses the torque on the **measured** force, as Algorithm 1 (eq. 14) and the batch fit
do. In free motion ``f = w_S + bias_force_S`` (w_S the weight in S) and

    τ = cog_S × w_S + bias_torque_S = cog_S × f + b',   b' = bias_torque_S − cog_S × bias_force_S,

so its state is x_t = [cog_S, b'] (6,) with C_k = [−[f]×, I3]: nothing of the force stage enters it. Regressed
on ``f − bias_force_S`` with the force stage's bias as it stood at each sample, an early or wandering bias (on a
log whose gravity and bias the motion barely tells apart) went into the centre of gravity for good: 1.5-8.6×
the batch fit's torque residual on the Axia80 logs; about the measured force, 0.7-1.0× on every real file.

Reported (``params``, warm-start files) and used for the contact torque is the physical bias,
bias_torque_S = b' + cog_S × bias_force_S. With ``J = [[I, 0], [[bias_force_S]×, I]]``, x_t = J x_phys and
P_t = J P_phys Jᵀ (the bias rates, with ``bias_rate``, are carried as they are).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.frames import skew


def _J(bias_force_S: np.ndarray, n: int, sign: float) -> np.ndarray:
    """(n, n) J (sign +1) or J⁻¹ (sign −1): identity but for the block [bias_force_S]× below the cog's."""
    J = np.eye(n)
    J[3:6, :3] = sign * skew(np.asarray(bias_force_S, float))
    return J


def to_physical(x_t: np.ndarray, P_t: np.ndarray, bias_force_S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[cog_S, b', ...] (n,) and its P (n, n) → [cog_S, bias_torque_S, ...] and its P, for ``bias_force_S`` (3,) N."""
    J_inv = _J(bias_force_S, len(x_t), -1.0)
    return J_inv @ x_t, J_inv @ P_t @ J_inv.T


def from_physical(x: np.ndarray, P: np.ndarray, bias_force_S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`to_physical`."""
    J = _J(bias_force_S, len(x), 1.0)
    return J @ x, J @ P @ J.T
