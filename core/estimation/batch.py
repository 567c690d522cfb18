"""Batch least squares of the paper's model over many samples (paper eq. 24).

Force: S_f = R_EB·B_f + f0, stacked over n samples as y = C x (eq. 22) and
solved for x = [gravity_force_B, bias_force_S]. Torque: S_tau = p × Δf + tau0
with Δf = S_f − f0 (eq. 30); since p × (S_f − f0) + tau0 = p × S_f + (tau0 − p × f0),
the torque fit uses the measured force directly and recovers tau0 afterwards,
which gives the same least-squares solution without a second pass.

This is the offline baseline the paper argues against (Yu et al. 2021 and
others): it needs the data first. ``batch_fit`` solves a whole recording;
``normal_terms`` gives the per-sample terms CᵀC and Cᵀy that the recursive
(``plugins.estimators.rls.information_form``) and running (``batch`` estimator) solutions accumulate.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.estimation.model import contact_wrench
from hapticlab.core.frames import skew_stack

I3 = np.eye(3)


def normal_terms(y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample C_kᵀC_k (m, 6, 6) and C_kᵀy_k (m, 6) for C_k = [A_k, I3].

    Args:
        y: (m, 3) measurements. A: (m, 3, 3) the A_k of each sample.
    """
    m = len(y)
    At = A.transpose(0, 2, 1)
    CtC = np.empty((m, 6, 6))
    CtC[:, :3, :3] = At @ A
    CtC[:, :3, 3:] = At
    CtC[:, 3:, :3] = A
    CtC[:, 3:, 3:] = I3
    Cty = np.empty((m, 6))
    Cty[:, :3] = (At @ y[:, :, None])[:, :, 0]
    Cty[:, 3:] = y
    return CtC, Cty


def batch_fit(force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray) -> dict[str, np.ndarray]:
    """Least-squares parameters of the paper's model over whole arrays.

    Args:
        force_S: (N, 3) raw force, N. torque_S: (N, 3) raw torque, N·m.
        R_EB: (N, 3, 3) orientation of B in E.

    Returns:
        ``gravity_force_B``, ``bias_force_S`` (N), ``cog_S`` (m), ``bias_torque_S`` (N·m),
        and the residuals ``residual_force_S`` (N, 3), ``residual_torque_S`` (N, 3).
    """
    n = len(force_S)
    C_f = np.concatenate([R_EB, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2).reshape(3 * n, 6)
    x_f = np.linalg.lstsq(C_f, force_S.reshape(-1), rcond=None)[0]
    gravity_force_B, bias_force_S = x_f[:3], x_f[3:]

    A_t = -skew_stack(force_S)
    C_t = np.concatenate([A_t, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2).reshape(3 * n, 6)
    x_t = np.linalg.lstsq(C_t, torque_S.reshape(-1), rcond=None)[0]
    cog_S = x_t[:3]
    bias_torque_S = x_t[3:] + np.cross(cog_S, bias_force_S)

    residual_force_S, residual_torque_S = contact_wrench(
        force_S, torque_S, R_EB, np.tile(x_f, (n, 1)), np.tile(np.concatenate([cog_S, bias_torque_S]), (n, 1))
    )
    return {
        "gravity_force_B": gravity_force_B,
        "bias_force_S": bias_force_S,
        "cog_S": cog_S,
        "bias_torque_S": bias_torque_S,
        "residual_force_S": residual_force_S,
        "residual_torque_S": residual_torque_S,
    }
