"""Algorithm 1 of the paper, transcribed line by line over whole arrays.

This is the reference the live estimator (``hapticlab.plugins.estimators.rls``)
is tested against: it builds every C_k explicitly and uses the textbook
formulas with a general matrix inverse, exactly as printed (eqs. 26–28, 20–21),
so any shortcut the fast implementation takes must give the same numbers.
It is slow (general inverses per sample); use it for tests and checks, not sessions.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.frames import skew


def algorithm1(
    force_S: np.ndarray,
    torque_S: np.ndarray,
    R_EB: np.ndarray,
    force_threshold: float,
    torque_threshold: float,
    x0_force: np.ndarray,
    x0_torque: np.ndarray,
    P0: float = 1e6,
    R: float = 2.5e-3,
    epsilon: float = 1e-3,
    joseph: bool = False,
) -> dict[str, np.ndarray]:
    """Run the paper's cascaded RLS over N samples.

    Args:
        force_S: (N, 3) raw sensor force, N.
        torque_S: (N, 3) raw sensor torque, N·m.
        R_EB: (N, 3, 3) orientation of B in E from forward kinematics.
        force_threshold, torque_threshold: contact thresholds f_th (N), τ_th (N·m).
        x0_force, x0_torque: (6,) initial estimates (the paper draws them at random).
        P0, R, epsilon: initial covariance scale, measurement noise, convergence threshold.
        joseph: evaluate eq. 28 in Joseph form, (I−KC) P (I−KC)ᵀ + K R Kᵀ: the same
            algebra, but accurate in double precision with P0 = 1e6 (as printed,
            (I−KC) P moves the contact force by up to ~2 N in the first samples;
            docs/estimators.md, rls).

    Returns:
        Per-sample arrays: ``contact_force_S`` (N, 3), ``contact_torque_S`` (N, 3),
        ``x_force`` (N, 6), ``x_torque`` (N, 6), ``converged_force`` (N,),
        ``converged_torque`` (N,), ``updated_force`` (N,), ``updated_torque`` (N,).
    """
    n = len(force_S)
    I3 = np.eye(3)
    x_f = np.array(x0_force, dtype=float)
    x_t = np.array(x0_torque, dtype=float)
    P_f = P0 * np.eye(6)
    P_t = P0 * np.eye(6)
    R_f = R * np.eye(3)
    R_t = R * np.eye(3)
    converged_f = converged_t = False
    out = {
        "contact_force_S": np.zeros((n, 3)),
        "contact_torque_S": np.zeros((n, 3)),
        "x_force": np.zeros((n, 6)),
        "x_torque": np.zeros((n, 6)),
        "converged_force": np.zeros(n, bool),
        "converged_torque": np.zeros(n, bool),
        "updated_force": np.zeros(n, bool),
        "updated_torque": np.zeros(n, bool),
    }
    for k in range(n):
        C_f = np.hstack([R_EB[k], I3])
        y_f = force_S[k]
        r_f = np.linalg.norm(C_f @ x_f - y_f)
        if r_f < force_threshold or not converged_f:
            K = P_f @ C_f.T @ np.linalg.inv(R_f + C_f @ P_f @ C_f.T)
            x_new = x_f + K @ (y_f - C_f @ x_f)
            P_f = _covariance_update(P_f, K, C_f, R_f, joseph)
            converged_f = bool(np.linalg.norm(x_new - x_f) < epsilon)
            x_f = x_new
            out["updated_force"][k] = True
        gravity_force_B, bias_force_S = x_f[:3], x_f[3:]
        out["contact_force_S"][k] = force_S[k] - R_EB[k] @ gravity_force_B - bias_force_S

        if converged_f:
            delta_f = force_S[k] - bias_force_S
            C_t = np.hstack([-skew(delta_f), I3])
            y_t = torque_S[k]
            r_t = np.linalg.norm(C_t @ x_t - y_t)
            if r_t < torque_threshold or not converged_t:
                K = P_t @ C_t.T @ np.linalg.inv(R_t + C_t @ P_t @ C_t.T)
                x_new = x_t + K @ (y_t - C_t @ x_t)
                P_t = _covariance_update(P_t, K, C_t, R_t, joseph)
                converged_t = bool(np.linalg.norm(x_new - x_t) < epsilon)
                x_t = x_new
                out["updated_torque"][k] = True
        cog_S, bias_torque_S = x_t[:3], x_t[3:]
        out["contact_torque_S"][k] = torque_S[k] - skew(cog_S) @ R_EB[k] @ gravity_force_B - bias_torque_S
        out["x_force"][k] = x_f
        out["x_torque"][k] = x_t
        out["converged_force"][k] = converged_f
        out["converged_torque"][k] = converged_t
    return out


def _covariance_update(P: np.ndarray, K: np.ndarray, C: np.ndarray, R: np.ndarray, joseph: bool) -> np.ndarray:
    """Eq. 28, as printed or in Joseph form."""
    IKC = np.eye(len(P)) - K @ C
    if joseph:
        return IKC @ P @ IKC.T + K @ R @ K.T
    return IKC @ P
