"""``batch``: least squares over every sample seen so far (the paper's baseline).

The offline method the paper argues against (eq. 24; Yu et al. 2021): no prior,
no gating, every sample is a calibration sample, so contact leaks into the
parameters. At each sample k it uses the least-squares solution over samples
0..k (minimum-norm while the poses seen so far do not yet determine it), or,
with ``calibration_samples = n``, fits the first n samples and then holds the
parameters, which is how a calibrate-then-use workflow runs.

Bad input (docs/estimators.md, "Refused samples"): a sample with a NaN or inf,
an R_EB that is not a rotation, or a force or torque component beyond
``max_force`` / ``max_torque`` is refused before the fit sees it (it does not
count towards ``calibration_samples`` either); its row is NaN, no contact, with
the flags of the row before; ``refused_samples`` counts them and
``drain_events()`` reports them (``sample_refused``). A block whose solve fails
(``LinAlgError``) leaves the fit as it was and its samples not converged.

Speed (options ``kernel``, ``solver``): the convergence flags are proved by a compiled Cholesky test
where it can (``conditioned_kernel``; the reference's SVD elsewhere, the same flags); the fit is numpy's
pinv per sample (the reference's numbers) or, with ``solver = "cholesky"``, a Cholesky solve where proved
well conditioned (the same solution within rounding, ~2.5x faster than pinv, not the same bits).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hapticlab.core.estimation.batch import normal_terms
from hapticlab.core.estimation.model import RefusesBadSamples, SampleGuard, contact_wrench, named_params
from hapticlab.core.frames import cross, skew_stack
from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.plugins.estimators.batch import conditioned_kernel
from hapticlab.plugins.estimators.batch.options import BatchOptions


class _RunningFit:
    """Least squares over a growing sample set, solved after every sample.

    Attributes: CtC (6, 6), Cty (6,) the sums so far; x (6,) the solution; converged whether its
    conditioning reaches ``min_rcond`` (``add``); failed: samples left out because their solve failed.
    """

    def __init__(self, min_rcond: float, kernel: str, solver: str):
        self.min_rcond = min_rcond
        self.compiled = kernel == "numba"
        self.cholesky = solver == "cholesky"
        self.CtC = np.zeros((6, 6))
        self.Cty = np.zeros(6)
        self.x = np.zeros(6)
        self.converged = False
        self.failed = 0

    def add(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add m samples; return x (m, 6) and whether the fit counts as converged (m,) after each one.

        If the solve fails (``LinAlgError``, e.g. "SVD did not converge"), nothing is added:
        x stays as it was and the m samples are not converged.
        """
        CtC, Cty = normal_terms(y, A)
        CtC = np.cumsum(CtC, axis=0) + self.CtC
        Cty = np.cumsum(Cty, axis=0) + self.Cty
        # conditioning after scaling each parameter to unit diagonal (the units differ); a
        # parameter no sample has touched yet (a zero diagonal: its row is zero) scales by 1
        d = np.sqrt(np.einsum("kii->ki", CtC))
        d = np.where(d > 0, d, 1.0)
        scaled = CtC / (d[:, :, None] * d[:, None, :])
        code = None
        if self.compiled or self.cholesky:
            code = np.empty(len(scaled), dtype=np.int8)
            conditioned_kernel.certain(scaled, self.min_rcond, code)
        try:
            converged = self._converged(scaled, code)
            X = self._solve(CtC, Cty, scaled, d, code)
        except np.linalg.LinAlgError:
            self.failed += len(y)
            return np.broadcast_to(self.x, (len(y), 6)).copy(), np.zeros(len(y), dtype=bool)
        self.CtC, self.Cty, self.x, self.converged = CtC[-1], Cty[-1], X[-1], bool(converged[-1])
        return X, converged

    def _converged(self, scaled: np.ndarray, code: np.ndarray | None) -> np.ndarray:
        """(m,) whether gesdd's reciprocal condition number of each scaled matrix is at least ``min_rcond``.

        With the kernel's ``code`` (``conditioned_kernel.certain``) gesdd is asked only where it proved nothing.
        """
        if not self.compiled or code is None:
            s = np.linalg.svd(scaled, compute_uv=False)
            return s[:, -1] / s[:, 0] >= self.min_rcond
        converged = code == conditioned_kernel.UP
        if not converged.all():
            rest = np.flatnonzero(~converged)
            s = np.linalg.svd(scaled[rest], compute_uv=False)
            converged[rest] = s[:, -1] / s[:, 0] >= self.min_rcond
        return converged

    def _solve(
        self, CtC: np.ndarray, Cty: np.ndarray, scaled: np.ndarray, d: np.ndarray, code: np.ndarray | None
    ) -> np.ndarray:
        """(m, 6) the minimum-norm least-squares solutions: numpy's pinv, or (``solver = "cholesky"``) the
        Cholesky solve where the kernel proved the scaled matrix well conditioned and pinv elsewhere."""
        if not self.cholesky or code is None:
            return (np.linalg.pinv(CtC, rcond=1e-12) @ Cty[:, :, None])[:, :, 0]
        X = np.empty((len(CtC), 6))
        conditioned_kernel.solve(scaled, d, Cty, code, X)
        rest = np.flatnonzero(code != conditioned_kernel.UP)
        if len(rest):
            X[rest] = (np.linalg.pinv(CtC[rest], rcond=1e-12) @ Cty[rest, :, None])[:, :, 0]
        return X

    def cov_diag(self) -> np.ndarray:
        """(6,) diagonal of (CᵀC)⁺ (inf if its SVD fails)."""
        try:
            return np.diag(np.linalg.pinv(self.CtC))
        except np.linalg.LinAlgError:
            return np.full(6, np.inf)


class BatchEstimator(RefusesBadSamples):
    """Least squares of the paper's model over the samples seen so far.

    Options: :class:`BatchOptions` (``BatchEstimator(calibration_samples=500)`` or ``BatchEstimator(options)``).

    Attributes:
        force, torque: the two running fits (the torque one of [cog_S, bias_torque_S − cog_S × bias_force_S]).
        samples: samples seen, refused ones included. fitted: samples given to the fits.
        refused_samples: samples refused as bad input.
        failed_solves: samples left out because a fit's solve failed.
    """

    Options = BatchOptions

    def __init__(self, options: BatchOptions | None = None, /, **settings: Any):
        o = self.options = options if options is not None else BatchOptions(**settings)
        calibration_samples, force_threshold, torque_threshold, min_rcond = (
            o.calibration_samples,
            o.force_threshold,
            o.torque_threshold,
            o.min_rcond,
        )
        self.guard = SampleGuard("batch", o.max_force, o.max_torque)
        self.calibration_samples = calibration_samples
        self.force_threshold = force_threshold
        self.torque_threshold = torque_threshold
        self.min_rcond = min_rcond
        self.kernel = o.kernel
        if o.kernel == "numba" or o.solver == "cholesky":
            conditioned_kernel.warm_up()
        self.force = _RunningFit(min_rcond, o.kernel, o.solver)
        self.torque = _RunningFit(min_rcond, o.kernel, o.solver)
        self.samples = 0
        self.fitted = 0

    def update_block(self, block: AlignedSamples) -> Estimates:
        """Contact wrench of each sample with the fit over the samples up to it (bad samples refused first)."""
        flags = (self.force.converged, self.torque.converged)
        out = self.guard.run(block, self._update, flags)
        self.samples += len(block)
        return out

    def _update(self, block: AlignedSamples) -> Estimates:
        """The fit over samples that passed the guard."""
        m = len(block)
        force_S, torque_S, R_EB = block.force_S, block.torque_S, block.R_EB
        n_fit = m if not self.calibration_samples else max(0, min(m, self.calibration_samples - self.fitted))
        X_f = np.broadcast_to(self.force.x, (m, 6)).copy()
        X_t = np.broadcast_to(self.torque.x, (m, 6)).copy()
        ok_f = np.full(m, self.force.converged)
        ok_t = np.full(m, self.torque.converged)
        if n_fit:
            X_f[:n_fit], ok_f[:n_fit] = self.force.add(force_S[:n_fit], R_EB[:n_fit])
            X_t[:n_fit], ok_t[:n_fit] = self.torque.add(torque_S[:n_fit], -skew_stack(force_S[:n_fit]))
            X_f[n_fit:], X_t[n_fit:] = X_f[n_fit - 1], X_t[n_fit - 1]
            ok_f[n_fit:], ok_t[n_fit:] = ok_f[n_fit - 1], ok_t[n_fit - 1]
        # The torque fit is linear in [p, tau0 − p × f0]; recover tau0.
        X_t[:, 3:] += cross(X_t[:, :3], X_f[:, 3:])
        contact_force_S, contact_torque_S = contact_wrench(force_S, torque_S, R_EB, X_f, X_t)
        self.fitted += n_fit
        return Estimates(
            t_ns=block.t_ns,
            contact_force_S=contact_force_S,
            contact_torque_S=contact_torque_S,
            contact=(np.linalg.norm(contact_force_S, axis=1) >= self.force_threshold)
            | (np.linalg.norm(contact_torque_S, axis=1) >= self.torque_threshold),
            converged_force=ok_f,
            converged_torque=ok_t,
        )

    def params(self) -> dict[str, list[float]]:
        """Fitted parameters with physical names (SI units)."""
        x_f, x_t = self.force.x, self.torque.x.copy()
        x_t[3:] += np.cross(x_t[:3], x_f[3:])  # tau0 from the fitted tau0 − p × f0
        return named_params(x_f, x_t)

    def cov_diag(self) -> list[float]:
        """Diagonal of (CᵀC)⁺ for force then torque: the unscaled parameter covariance."""
        return np.concatenate([self.force.cov_diag(), self.torque.cov_diag()]).tolist()
