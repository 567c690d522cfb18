"""One RLS stage in the paper's covariance form, exactly as printed (eqs. 26–28).

Measurement model as in ``plugins.estimators.rls.information_form``: y_k = C_k x + v_k, C_k = [A_k, I3],
v_k ~ N(0, R), R = r·I3. Each sample, in order (Simon 2006, §3.3):

    K_k = P_{k−1} C_kᵀ (R + C_k P_{k−1} C_kᵀ)⁻¹      (eq. 27)
    x_k = x_{k−1} + K_k (y_k − C_k x_{k−1})          (eq. 26)
    P_k = (I − K_k C_k) P_{k−1}                      (eq. 28)

In exact arithmetic this is the estimate ``plugins.estimators.rls.information_form`` computes in information
form. In double precision with P_0 = 1e6·I and r = 2.5e-3 it is not: (I − K C) P
subtracts entries of size ~1e6 to leave entries of size ~r in the directions a
sample has seen, so their rounding (~1e6·2⁻⁵³ ≈ 1e-10) is a relative error of
~1e-8 there; P_k is not kept symmetric, and the gains built from it pass the
error on to x. How far that moves the estimate depends on the data and on how
the BLAS rounds: most in the first samples when the orientation changes at
every sample, little on a slow tour. As samples accumulate the gains shrink
and the deviation decays (docs/estimators.md, ``rls``, measures it).

It is the ``rls`` default (``covariance_update = "printed"``): the paper's numbers are this update's,
rounding included. This module is the numpy reference (``kernel = "numpy"``) of
``covariance_form_kernel``. It performs the same operations in the same order as
``plugins.estimators.rls.algorithm1`` with ``joseph=False``, so the two agree to the last bit
wherever they see the same numbers.
"""

from __future__ import annotations

import numpy as np

from hapticlab.plugins.estimators.rls.information_form import RecursiveLeastSquares

I6 = np.eye(6)
I3 = np.eye(3)


def printed_update(
    x: np.ndarray, P: np.ndarray, y: np.ndarray, C: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One sample of eqs. 26–28 as printed: returns (x_k (6,), P_k (6, 6), K_k (6, 3)).

    Args:
        x: (6,) x_{k−1}. P: (6, 6) P_{k−1}.
        y: (3,) measurement y_k. C: (3, 6) measurement matrix C_k. R: (3, 3) noise covariance.
    """
    K = P @ C.T @ np.linalg.inv(R + C @ P @ C.T)  # (6, 3), eq. 27
    x = x + K @ (y - C @ x)  # eq. 26
    P = (I6 - K @ C) @ P  # eq. 28, not symmetrised
    return x, P, K


class PrintedRecursiveLeastSquares:
    """One RLS stage with C_k = [A_k, I3], updated by ``printed_update``.

    The same interface as ``plugins.estimators.rls.information_form.RecursiveLeastSquares`` (``predict``,
    ``propose``, ``propose_one``, ``commit``), so ``plugins.estimators.rls.information_form.run_gated`` runs
    Algorithm 1's gating and convergence test on it unchanged; a proposal is
    (x, P, K) instead of (x, Λ, η).

    Attributes:
        x: (6,) current estimate x_k.
        P: (6, 6) estimation-error covariance P_k as the printed update leaves it.
        K: (6, 3) gain K_k of the last update used (zeros before the first).
        R: (3, 3) measurement-noise covariance r·I3 (units of y squared).
        updates: number of samples used so far.
        failed: samples left out because their update failed (``plugins.estimators.rls.information_form.run_gated``).
    """

    predict = RecursiveLeastSquares.predict  # C_k x from x alone: the same in both forms

    def __init__(self, x0: np.ndarray, P0: float, R: float):
        self.x = np.array(x0, dtype=float).reshape(6)
        self.P = P0 * np.eye(6)
        self.K = np.zeros((6, 3))
        self.R = R * np.eye(3)
        self.updates = 0
        self.failed = 0

    def restart(self, P0: float) -> None:
        """Start again from the current estimate x with P = P0·I: what was learnt is forgotten."""
        self.P = P0 * np.eye(6)

    def propose(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Estimates after each of m samples if every one of them is used, one sample at a time.

        Args:
            y: (m, 3) measurements. A: (m, 3, 3) the A_k of each sample.

        Returns:
            (X, Ps, Ks): (m, 6) x, (m, 6, 6) P and (m, 6, 3) K after each
            sample. Nothing is changed until ``commit``.
        """
        m = len(y)
        X = np.empty((m, 6))
        Ps = np.empty((m, 6, 6))
        Ks = np.empty((m, 6, 3))
        x, P = self.x, self.P
        for j in range(m):
            x, P, K = printed_update(x, P, y[j], np.hstack([A[j], I3]), self.R)
            X[j], Ps[j], Ks[j] = x, P, K
        return X, Ps, Ks

    def propose_one(self, y: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``propose`` for one sample, y (3,) and A (3, 3): returns (x (6,), P (6, 6), K (6, 3))."""
        return printed_update(self.x, self.P, y, np.hstack([A, I3]), self.R)

    def commit(self, x: np.ndarray, P: np.ndarray, K: np.ndarray, used: int) -> None:
        """Make a proposed state (after ``used`` more samples) the current one."""
        self.x, self.P, self.K = x, P, K
        self.updates += used
