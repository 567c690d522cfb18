"""The torque stage's bias about the measured force: what it estimates, and the physical bias it reports.

The torque stage regresses the torque on the **measured** force, as the batch fit does (Algorithm 1
regresses on ``f − bias_force_S`` with the force stage's bias as it stands, once that stage has converged).
In free motion ``f = w_S + bias_force_S`` (w_S the weight in S) and

    τ = cog_S × w_S + bias_torque_S = cog_S × f + b',   b' = bias_torque_S − cog_S × bias_force_S,

so its state is x_t = [cog_S, b'] (6,) with C_k = [−[f]×, I3]: nothing of the force stage enters it. Regressed
on ``f − bias_force_S`` with the force stage's bias as it stood at each sample, an early or wandering bias (on a
log whose gravity and bias the motion barely tells apart) went into the centre of gravity for good: 1.5-8.6×
the batch fit's torque residual on the Axia80 logs; about the measured force, 0.7-1.0× on every real file.

Reported (``params``, in warm-start files too) and used for the contact torque is the physical bias,
bias_torque_S = b' + cog_S × bias_force_S. With ``J = [[I, 0], [[bias_force_S]×, I]]``, x_t = J x_phys and
P_t = J P_phys Jᵀ (with ``bias_rate``, the rates' rows too; the covariance between the stages is not carried).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.frames import skew


def _J(bias_force_S: np.ndarray, n: int, sign: float, bias_force_rate_S: np.ndarray | None) -> np.ndarray:
    """(n, n) J (sign +1) or J⁻¹ (sign −1): identity but for [bias_force_S]× below the cog's block (and, with
    the bias rates, [bias_force_rate_S]× below it in the rates' rows: b'´s rate is the bias's rate − cog_S × the
    force bias's rate)."""
    J = np.eye(n)
    J[3:6, :3] = sign * skew(np.asarray(bias_force_S, float))
    if n > 6 and bias_force_rate_S is not None:
        J[6:9, :3] = sign * skew(np.asarray(bias_force_rate_S, float))
    return J


def to_physical(
    x_t: np.ndarray, P_t: np.ndarray, bias_force_S: np.ndarray, bias_force_rate_S: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """[cog_S, b', (rate)] (n,) and its P (n, n) → [cog_S, bias_torque_S, (rate)] and its P, for the force stage's
    ``bias_force_S`` (3,) N (and ``bias_force_rate_S``, N/s, with the rates)."""
    J_inv = _J(bias_force_S, len(x_t), -1.0, bias_force_rate_S)
    return J_inv @ x_t, J_inv @ P_t @ J_inv.T


def physical(x_t: np.ndarray, bias_force_S: np.ndarray, bias_force_rate_S: np.ndarray | None = None) -> np.ndarray:
    """The state alone, as :func:`to_physical` turns it (``params`` asks for it every block: no P to turn)."""
    return _J(bias_force_S, len(x_t), -1.0, bias_force_rate_S) @ x_t


def from_physical(
    x: np.ndarray, P: np.ndarray, bias_force_S: np.ndarray, bias_force_rate_S: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`to_physical`."""
    J = _J(bias_force_S, len(x), 1.0, bias_force_rate_S)
    return J @ x, J @ P @ J.T


def information_from_physical(info: np.ndarray, bias_force_S: np.ndarray) -> np.ndarray:
    """Λ (6, 6) of [cog_S, bias_torque_S] → Λ of [cog_S, b']: J⁻ᵀ Λ J⁻¹ (the inverse of P → J P Jᵀ)."""
    J_inv = _J(bias_force_S, 6, -1.0, None)
    return J_inv.T @ info @ J_inv
