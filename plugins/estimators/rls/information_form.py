"""Recursive least squares for one stage of the paper's cascade (Algorithm 1).

Measurement model (paper eqs. 22 and 32; Simon 2006, §3.3):

    y_k = C_k x + v_k,    C_k = [A_k, I3],    v_k ~ N(0, r·I3)

Both stages of Algorithm 1 have this shape: the force stage has
``A_k = R_EB`` and ``x = [gravity_force_B, bias_force_S]``; the torque stage
has ``A_k = -skew(force_S - bias_force_S)`` and ``x = [cog_S, bias_torque_S]``.

The paper writes the update in covariance form (eqs. 26–28). Started from
x_0 and P_0, k such updates give exactly the regularised least-squares
solution over the samples used so far:

    Λ_k = P_0⁻¹ + Σ C_jᵀ C_j / r        (information matrix, Λ_k = P_k⁻¹)
    η_k = P_0⁻¹ x_0 + Σ C_jᵀ y_j / r    (information vector)
    x_k = Λ_k⁻¹ η_k

We evaluate that information form. It is the same estimate at every sample,
but it stays accurate where the printed covariance update does not: with
P_0 = 1e6·I and r = 2.5e-3, ``P_k = (I − K_k C_k) P_{k−1}`` in double precision
moves the contact force by up to ~2 N in the first samples when the poses
change fast (docs/estimators.md, ``rls``), then less and less, while the
information form agrees with the Joseph-form update (1e-6 in x over the first
ten samples, 1e-8 after). ``plugins.estimators.rls.covariance_form`` runs the printed update (the
``rls`` option ``covariance_update = "printed"``). Λ is a sum of symmetric
terms, so it stays symmetric over any run; P = Λ⁻¹ is formed only when asked for.

The information form also lets a block of samples that arrive together (a
7 kHz sensor read by a 1 kHz loop, or an offline file) be evaluated with one
cumulative sum and one batched solve, giving x_k after every sample of the
block at a fraction of the per-sample cost.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from scipy.linalg.lapack import dposv

from hapticlab.core.estimation.batch import I3, normal_terms


class RecursiveLeastSquares:
    """One RLS stage with measurement matrix C_k = [A_k, I3].

    Attributes:
        x: (6,) current estimate x_k.
        Lambda: (6, 6) information matrix Λ_k = P_k⁻¹.
        eta: (6,) information vector η_k = Λ_k x_k.
        r: measurement-noise variance, R = r·I3 (units of y squared).
        updates: number of samples used so far.
        failed: samples left out because their solve failed (``run_gated``).
    """

    def __init__(self, x0: np.ndarray, P0: float, R: float):
        self.x = np.array(x0, dtype=float).reshape(6)
        self.Lambda = np.eye(6) / P0
        self.eta = self.Lambda @ self.x
        self.r = float(R)
        self.updates = 0
        self.failed = 0

    def restart(self, P0: float) -> None:
        """Start again from the current estimate x with P = P0·I (Λ = I/P0, η = Λ x): what was learnt is forgotten."""
        self.Lambda = np.eye(6) / P0
        self.eta = self.Lambda @ self.x

    @property
    def P(self) -> np.ndarray:
        """(6, 6) estimation-error covariance P_k = Λ_k⁻¹ (inf if Λ cannot be inverted: nothing is known)."""
        try:
            return np.linalg.inv(self.Lambda)
        except np.linalg.LinAlgError:
            return np.full((6, 6), np.inf)

    def predict(self, A: np.ndarray, x: np.ndarray | None = None) -> np.ndarray:
        """(m, 3) measurements C_k x predicted for (m, 3, 3) A by x (default: the current estimate)."""
        x = self.x if x is None else x
        return A @ x[:3] + x[3:]

    def propose(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Estimates after each of m samples if every one of them is used.

        Args:
            y: (m, 3) measurements. A: (m, 3, 3) the A_k of each sample.

        Returns:
            (X, Lam, eta): (m, 6) x after each sample, (m, 6, 6) Λ and (m, 6) η
            after each sample. Nothing is changed until ``commit``.
        """
        CtC, Cty = normal_terms(y, A)
        Lam = np.cumsum(CtC, axis=0)
        Lam *= 1.0 / self.r
        Lam += self.Lambda
        eta = np.cumsum(Cty, axis=0)
        eta *= 1.0 / self.r
        eta += self.eta
        X = np.linalg.solve(Lam, eta[:, :, None])[:, :, 0]
        return X, Lam, eta

    def propose_one(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``propose`` for one sample, y (3,) and A (3, 3): returns (x (6,), Λ (6, 6), η (6,)).

        The same sums as ``propose`` without the block machinery (cumulative
        sums and a batched solve), for a live loop that gets one sample at a time.
        """
        At = A.T
        Lam = np.empty((6, 6))
        Lam[:3, :3] = At @ A
        Lam[:3, 3:] = At
        Lam[3:, :3] = A
        Lam[3:, 3:] = I3
        Lam *= 1.0 / self.r
        Lam += self.Lambda
        eta = np.concatenate((At @ y, y))
        eta *= 1.0 / self.r
        eta += self.eta
        _, x, info = dposv(Lam, eta)  # Cholesky: Λ is symmetric positive definite
        if info:  # not numerically positive definite: the general solver
            x = np.linalg.solve(Lam, eta)
        return x, Lam, eta

    def commit(self, x: np.ndarray, Lam: np.ndarray, eta: np.ndarray, used: int) -> None:
        """Make a proposed state (after ``used`` more samples) the current one."""
        self.x, self.Lambda, self.eta = x, Lam, eta
        self.updates += used


class RLSStage(Protocol):
    """What ``run_gated`` and the estimator need of a stage: :class:`RecursiveLeastSquares`, or
    ``covariance_form.PrintedRecursiveLeastSquares``, whose proposals are (x, P, K) where this one's are (x, Λ, η)."""

    x: np.ndarray
    updates: int
    failed: int

    @property
    def P(self) -> np.ndarray: ...
    def restart(self, P0: float) -> None: ...
    def predict(self, A: np.ndarray, x: np.ndarray | None = None) -> np.ndarray: ...
    def propose(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    def propose_one(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]: ...
    def commit(self, x: np.ndarray, S1: np.ndarray, S2: np.ndarray, used: int, /) -> None: ...


HORIZON = 128
"""Most samples proposed or checked at once: after a cut, the rest is proposed
again, so an unbounded look-ahead would cost O(m²) when gates flicker."""


def run_gated(
    stage: RLSStage, y: np.ndarray, A: np.ndarray, active: np.ndarray, threshold: float, epsilon: float, converged: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """One stage of Algorithm 1 over a block of m samples, in order.

    For each active sample k: if the stage has converged and the residual norm
    ‖C_k x_{k−1} − y_k‖ is not below ``threshold`` (a NaN is not below it), the
    sample is taken as contact and not used; otherwise it updates x, and
    ``converged = ‖x_k − x_{k−1}‖ < epsilon``. Inactive samples (the torque
    stage while the force stage has not converged) leave everything unchanged.

    Runs of samples that all update are evaluated together (``propose``), and
    cut at the first sample the gate would refuse, so the result equals
    sample-by-sample processing.

    A numerical corner never raises: where a run's solve fails (``LinAlgError``)
    or gives a non-finite x, its first sample is taken alone; a sample whose own
    solve fails leaves the stage as it was (counted in ``stage.failed``), is not
    gated, and is marked not converged (the stage's flag is kept).

    Args:
        stage: the RLS stage, updated in place: a ``RecursiveLeastSquares``,
            or anything with its ``x``, ``predict``, ``propose``, ``propose_one``
            and ``commit`` (``plugins.estimators.rls.covariance_form``, whose proposals are (x, P, K)),
            and a ``failed`` count.
        y: (m, 3) measurements. A: (m, 3, 3) the A_k of each sample.
        active: (m,) bool, samples this stage sees.
        threshold: contact threshold on the residual norm (units of y).
        epsilon: convergence threshold on ‖Δx‖₂.
        converged: the stage's convergence flag before the block.

    Returns:
        (X, conv, gated, converged): (m, 6) estimate after each sample, (m,)
        convergence flag after each sample, (m,) True where the gate refused
        the sample, and the flag after the block.
    """
    m = len(y)
    if m == 1:  # the live loop's common case, without the run bookkeeping
        return _run_gated_one(stage, y, A, bool(active[0]), threshold, epsilon, converged)
    threshold2, epsilon2 = threshold * threshold, epsilon * epsilon  # compare squared norms
    X = np.empty((m, 6))
    conv = np.empty(m, dtype=bool)
    gated = np.zeros(m, dtype=bool)
    i = 0
    while i < m:
        if not active[i]:
            n = _leading_true_count(~active[i : i + HORIZON])
            X[i : i + n] = stage.x
            conv[i : i + n] = converged
            i += n
            continue
        end = i + _leading_true_count(active[i : i + HORIZON])
        if converged:
            residual = stage.predict(A[i:end]) - y[i:end]
            n = _leading_true_count(~(np.einsum("ij,ij->i", residual, residual) < threshold2))
            if n:
                X[i : i + n] = stage.x
                conv[i : i + n] = True
                gated[i : i + n] = True
                i += n
                continue
        try:
            Xp, S1, S2 = stage.propose(y[i:end], A[i:end])  # x and the stage's (Λ, η) or (P, K) after each sample
        except np.linalg.LinAlgError:
            Xp = None
        if Xp is not None:
            dx = Xp.copy()
            dx[0] -= stage.x
            dx[1:] -= Xp[:-1]
            step2 = np.einsum("ij,ij->i", dx, dx)
        if Xp is None or not np.maximum.reduce(step2) < math.inf:  # a numerical corner: this sample alone
            X[i : i + 1], conv[i : i + 1], gated[i : i + 1], converged = _run_gated_one(
                stage, y[i : i + 1], A[i : i + 1], True, threshold, epsilon, converged
            )
            i += 1
            continue
        conv_p = step2 < epsilon2
        # Would the gate refuse the sample after each one? (needs x and the flag after it)
        residual_next = (A[i + 1 : end] @ Xp[:-1, :3, None])[:, :, 0] + Xp[:-1, 3:] - y[i + 1 : end]
        stop = conv_p[:-1] & ~(np.einsum("ij,ij->i", residual_next, residual_next) < threshold2)
        n = int(np.argmax(stop)) + 1 if stop.any() else end - i
        stage.commit(Xp[n - 1], S1[n - 1], S2[n - 1], n)
        converged = bool(conv_p[n - 1])
        X[i : i + n] = Xp[:n]
        conv[i : i + n] = conv_p[:n]
        i += n
    return X, conv, gated, converged


def _run_gated_one(stage, y, A, active, threshold, epsilon, converged):
    """``run_gated`` for a single sample: the same rules, fewer array operations."""
    if active:
        residual = A[0] @ stage.x[:3] + stage.x[3:] - y[0]
        if converged and not residual @ residual < threshold * threshold:
            return stage.x[None, :], np.ones(1, dtype=bool), np.ones(1, dtype=bool), converged
        try:
            x, S1, S2 = stage.propose_one(y[0], A[0])
        except np.linalg.LinAlgError:
            x = None
        if x is not None:
            dx = x - stage.x
            step2 = dx @ dx
        if x is None or not step2 < math.inf:  # the solve failed: the stage stays as it was
            stage.failed += 1
            return stage.x[None, :], np.zeros(1, dtype=bool), np.zeros(1, dtype=bool), converged
        converged = bool(step2 < epsilon * epsilon)
        stage.commit(x, S1, S2, 1)
        return x[None, :], np.array([converged]), np.zeros(1, dtype=bool), converged
    return stage.x[None, :], np.array([converged]), np.zeros(1, dtype=bool), converged


def _leading_true_count(flags: np.ndarray) -> int:
    """How many leading entries of a bool array are True."""
    if flags.all():
        return len(flags)
    return int(np.argmin(flags))
