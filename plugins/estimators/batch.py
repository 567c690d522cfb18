"""``batch``: least squares over every sample seen so far (the paper's baseline).

The offline method the paper argues against (eq. 24; Yu et al. 2021): no prior,
no gating, every sample is a calibration sample, so contact leaks into the
parameters. At each sample k it uses the least-squares solution over samples
0..k (minimum-norm while the poses seen so far do not yet determine it), or,
with ``calibration_samples = n``, fits the first n samples and then holds the
parameters, which is how a calibrate-then-use workflow runs.
"""

from __future__ import annotations

import numpy as np

from ...core import hookimpl
from ...core.batch import normal_terms
from ...core.frames import cross, skew_stack
from ...core.model import contact_wrench, named_params
from ...core.types import AlignedSamples, Estimates

class _RunningFit:
    """Least squares over a growing sample set, solved after every sample."""

    def __init__(self):
        self.CtC = np.zeros((6, 6))
        self.Cty = np.zeros(6)
        self.x = np.zeros(6)
        self.rcond = 0.0

    def add(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add m samples; return x (m, 6) and rcond (m,) after each one."""
        CtC, Cty = normal_terms(y, A)
        CtC = np.cumsum(CtC, axis=0) + self.CtC
        Cty = np.cumsum(Cty, axis=0) + self.Cty
        # conditioning after scaling each parameter to unit diagonal (the units differ)
        d = np.sqrt(np.einsum("kii->ki", CtC))
        scaled = CtC / (d[:, :, None] * d[:, None, :])
        s = np.linalg.svd(scaled, compute_uv=False)
        rcond = s[:, -1] / s[:, 0]
        X = (np.linalg.pinv(CtC, rcond=1e-12) @ Cty[:, :, None])[:, :, 0]
        self.CtC, self.Cty, self.x, self.rcond = CtC[-1], Cty[-1], X[-1], float(rcond[-1])
        return X, rcond


class BatchEstimator:
    """Least squares of the paper's model over the samples seen so far.

    Args:
        calibration_samples: 0 refits over every sample seen so far; n > 0 fits
            the first n samples and then holds the parameters.
        force_threshold: residual norm (N) reported as contact (no gating: the
            batch method has none; the flag is for comparison only).
        torque_threshold: the same for torque (N·m).
        min_rcond: the fit counts as converged once the normal matrix, scaled to
            unit diagonal, has a reciprocal condition number of at least this
            (the poses seen so far determine every parameter).
    """

    def __init__(
        self,
        calibration_samples: int = 0,
        force_threshold: float = 1.0,
        torque_threshold: float = 0.1,
        min_rcond: float = 1e-4,
    ):
        if calibration_samples < 0:
            raise ValueError(f"calibration_samples: must be >= 0, got {calibration_samples}")
        self.calibration_samples = calibration_samples
        self.force_threshold = force_threshold
        self.torque_threshold = torque_threshold
        self.min_rcond = min_rcond
        self.force = _RunningFit()
        self.torque = _RunningFit()
        self.samples = 0

    def update_block(self, block: AlignedSamples) -> Estimates:
        """Contact wrench of each sample with the fit over the samples up to it."""
        m = len(block)
        force_S, torque_S, R_EB = block.force_S, block.torque_S, block.R_EB
        n_fit = m if not self.calibration_samples else max(0, min(m, self.calibration_samples - self.samples))
        X_f = np.broadcast_to(self.force.x, (m, 6)).copy()
        X_t = np.broadcast_to(self.torque.x, (m, 6)).copy()
        rc_f = np.full(m, self.force.rcond)
        rc_t = np.full(m, self.torque.rcond)
        if n_fit:
            X_f[:n_fit], rc_f[:n_fit] = self.force.add(force_S[:n_fit], R_EB[:n_fit])
            X_t[:n_fit], rc_t[:n_fit] = self.torque.add(torque_S[:n_fit], -skew_stack(force_S[:n_fit]))
            X_f[n_fit:], X_t[n_fit:] = X_f[n_fit - 1], X_t[n_fit - 1]
            rc_f[n_fit:], rc_t[n_fit:] = rc_f[n_fit - 1], rc_t[n_fit - 1]
        # The torque fit is linear in [p, tau0 − p × f0]; recover tau0.
        X_t[:, 3:] += cross(X_t[:, :3], X_f[:, 3:])
        contact_force_S, contact_torque_S = contact_wrench(force_S, torque_S, R_EB, X_f, X_t)
        self.samples += m
        return Estimates(
            t_ns=block.t_ns,
            contact_force_S=contact_force_S,
            contact_torque_S=contact_torque_S,
            contact=(np.linalg.norm(contact_force_S, axis=1) >= self.force_threshold)
            | (np.linalg.norm(contact_torque_S, axis=1) >= self.torque_threshold),
            converged_force=rc_f >= self.min_rcond,
            converged_torque=rc_t >= self.min_rcond,
        )

    def params(self) -> dict[str, list[float]]:
        """Fitted parameters with physical names (SI units)."""
        x_f, x_t = self.force.x, self.torque.x.copy()
        x_t[3:] += np.cross(x_t[:3], x_f[3:])  # tau0 from the fitted tau0 − p × f0
        return named_params(x_f, x_t)

    def cov_diag(self) -> list[float]:
        """Diagonal of (CᵀC)⁺ for force then torque: the unscaled parameter covariance."""
        return np.concatenate(
            [np.diag(np.linalg.pinv(self.force.CtC)), np.diag(np.linalg.pinv(self.torque.CtC))]
        ).tolist()


@hookimpl
def register_estimators(register):
    register("batch", BatchEstimator)
