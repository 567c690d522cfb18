"""Kalman filter for one stage of the paper's cascade, with drifting sensor bias.

Measurement model of a stage (the same shape as ``plugins.estimators.rls.information_form``):

    y_k = A_k a + b_k + v_k,      v_k ~ N(0, R_k)

* force stage: y = force_S, A_k = R_EB, a = gravity_force_B, b = bias_force_S;
* torque stage: y = torque_S, A_k = -skew(force_S), a = cog_S, b = bias_torque_S - cog_S × bias_force_S
  (``torque_bias.py``).

Unlike the paper's RLS, the bias is not a constant: it is a random walk
(b_k = b_{k-1} + w_k, w_k ~ N(0, q·dt_k·I), q = rw², rw in units/√s), and with
``bias_rate`` a random walk plus an integrated one (ḃ = r + w_b, ṙ = w_r;
the state grows by r = bias rate, units/s). a (gravity, centre of gravity) is
constant. Discretised exactly over the time between samples dt_k:

    x = [a, b]      F = I6                         Q = diag(0, q_b·dt·I3)
    x = [a, b, r]   F = [I 0 0; 0 I dt·I; 0 0 I]   Q = [0 0 0; 0 q_b·dt + q_r·dt³/3  q_r·dt²/2; 0 q_r·dt²/2  q_r·dt]

The bias also walks with the tool's tilt (the "tilt walk"): Q's bias block gains
q_θ·Δθ_k, Δθ_k the angle gravity's direction turned in the sensor since the
previous sample (rad), q_θ in units²/rad. What the base model misses (a mount
or calibration error, a cable's pull, hysteresis) is a function of the tool's
orientation, so the bias that absorbs it moves when the tool tilts, not with
time; added before the prediction, it is the same for both F.

With a span s (rad) the walk's gain per axis is min(q_θ·Δθ_k, σ²·(Δθ_k/s)²), σ²
the stage's noise variance. A walk seen through white noise is followed over
about √(σ²·δ/q_θ) of turn (δ/K, K the steady-state gain), δ the turn per
sample: at a high sample rate that span is a small fraction of a radian, a few
tens of milliseconds of a turn, fast enough to take in the first newtons of a
contact's ramp before the gate refuses it. The cap keeps the tilt walk's own
span at s or more whatever the sample rate and the turn rate (the walk over
time, on top, follows on its own); the errors the walk stands for change
smoothly with the tilt, so a finer span follows noise and contacts, not them.
Over samples the stage does not test (a sensor status, a stale pose) the turn
adds up, and the whole turn Θ adds min(q_θ·Θ, σ²·(Θ/s)²), however finely it was
sampled (``stage_kernel.add_tilt_noise``, which every path runs: compiled, or as Python in the
filterpy reference and the mount's EKF; the unrolled ``filter6`` writes it out).

Measurement noise R_k: the sensor's per-axis variance, diag(σ²). The torque
stage's A_k is built from the *measured* force, whose noise enters the torque
equation through p × Δf, so its R_k adds [p]ₓ diag(σ_f²) [p]ₓᵀ at the current
estimate of p (for a centre of gravity a few centimetres out, about half a
Gamma-class sensor's torque noise itself).

Gating: before a sample updates the state, its innovation e = y − C x⁻ and
S = C P⁻ Cᵀ + R give the squared Mahalanobis distance d² = eᵀ S⁻¹ e; a
sample with d² above the gate (a chi-square quantile with 3 degrees of
freedom) is refused as contact: it does not update, but the prediction step
still runs, so P of the drift states keeps growing through a long contact.

Two implementations of exactly this filter, which agree to ~1e-11 (tests
hold them to 1e-9), chosen by ``KalmanStage.run(method=...)`` (the ``kalman``
estimator's ``implementation`` option):

* ``method="filterpy"``: ``filterpy.kalman.KalmanFilter`` does the
  predict/update bookkeeping per sample (Joseph-form covariance update). The
  reference, slow (a dozen numpy calls per sample); it is
  also what runs with ``bias_rate`` under ``kernel = "numpy"`` (the compiled cascade
  has its own step for them, ``plugins.estimators.kalman.stage_kernel.stage_step_rate``).
* ``method="numba"`` (x = [a, b]): ``filter6`` compiled (``plugins.estimators.kalman.stage_kernel``),
  the same bits; the ``kalman`` estimator's default (``kernel = "numba"``).
* ``method="fast"`` (x = [a, b], the default model): the same filter
  specialised to C = [A, I3] and a symmetric 6×6 P (21 numbers), unrolled in
  plain Python floats, so no numpy call happens per sample; S is factored as
  L·diag(d)·Lᵀ, which makes the update three decorrelated scalar updates and
  d² a sum of positive terms. (A closed-form adjugate inverse of S loses
  precision against the reference while P still holds a wide prior; the LDLᵀ
  form stays at rounding.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hapticlab.plugins.estimators.kalman import stage_kernel as kernel
from hapticlab.plugins.estimators.kalman.stage_reference import filter6

if TYPE_CHECKING:
    import numpy.typing as npt

I3 = np.eye(3)
add_tilt_noise = kernel.add_tilt_noise.py_func
"""The tilt walk's addition to the bias's variance, run as Python here (the compiled stage runs it compiled)."""

TILT_SPAN = 0.15
"""rad: the ``kalman`` estimator's default span of the tilt walk (``add_tilt_noise``), half the window of turn
over which ``tilt_walk_kernel`` measures it: a walk learnt at that scale says nothing finer (docs/estimators.md,
"Its span", measures the choice on the real recordings)."""


@dataclass
class StageRun:
    """What a stage did over a block of m samples.

    Attributes:
        X: (m, n) state after each sample (the prediction alone where the
            sample was inactive or refused).
        D: (m, n) diagonal of P after each sample.
        gated: (m,) True where the gate refused the sample.
        d2: (m,) squared Mahalanobis distance of the innovation (NaN where inactive).
        failed: (m,) True where the update could not be computed (S singular or
            not numerically positive definite): predicted only, not gated; None
            when every update could be.
    """

    X: np.ndarray
    D: np.ndarray
    gated: np.ndarray
    d2: np.ndarray
    failed: np.ndarray | None = None


class KalmanStage:
    """One stage: x = [a, b] or [a, b, ḃ], y_k = A_k a + b + v_k (see the module docstring).

    Args:
        prior_std: (n,) prior standard deviation of each state (units of the state).
        bias_rw: (3,) random-walk intensity of the bias, units/√s (q_b = rw²).
        noise: (3,) measurement noise std per axis (units of y).
        cross_noise: (3,) std of the noise of the vector A_k is built from
            (the torque stage: the force noise, N); zeros for the force stage.
        bias_rate_rw: (3,) random-walk intensity of the bias rate, units/s/√s,
            or None for no rate states.
        bias_tilt_rw: (3,) random-walk intensity of the bias per tilt, units/√rad (q_θ = rw²).
        tilt_span: rad, the least turn the bias follows its tilt walk over (0: the plain walk; ``add_tilt_noise``).

    Attributes:
        x: (n,) state. P: (n, n) covariance. n: 6, or 9 with bias-rate states.
        failed: samples whose update could not be computed (``StageRun.failed``).
    """

    def __init__(
        self,
        prior_std: npt.ArrayLike,
        bias_rw: npt.ArrayLike,
        noise: npt.ArrayLike,
        cross_noise: npt.ArrayLike = (0.0, 0.0, 0.0),
        bias_rate_rw: npt.ArrayLike | None = None,
        bias_tilt_rw: npt.ArrayLike = (0.0, 0.0, 0.0),
        tilt_span: float = 0.0,
    ) -> None:
        self.n = 6 if bias_rate_rw is None else 9
        prior_std = np.asarray(prior_std, dtype=float).reshape(self.n)
        self._lists: tuple[list, list] | None = None  # the fast path's state as Python floats
        self.x = np.zeros(self.n)
        self.P = np.diag(prior_std**2)
        self.q_bias = np.asarray(bias_rw, dtype=float).reshape(3) ** 2
        self.q_rate = None if bias_rate_rw is None else np.asarray(bias_rate_rw, dtype=float).reshape(3) ** 2
        self.q_tilt = np.asarray(bias_tilt_rw, dtype=float).reshape(3) ** 2
        self.tilt_span = float(tilt_span)
        self.turn = 0.0  # rad the tool turned since the stage last tested a sample (``add_tilt_noise``)
        self.r = np.asarray(noise, dtype=float).reshape(3) ** 2
        self.rc = np.asarray(cross_noise, dtype=float).reshape(3) ** 2
        self.failed = 0

    # The state lives either in numpy arrays (x, P) or, after the fast path ran,
    # in its Python lists; reading x or P turns the lists back into arrays (and
    # they stay the only copy, so changing x or P in place is safe).

    @property
    def x(self) -> np.ndarray:
        """(n,) the state."""
        self._materialise()
        return self._x

    @x.setter
    def x(self, value: np.ndarray) -> None:
        self._materialise()
        self._x = np.array(value, dtype=float).reshape(self.n)

    @property
    def P(self) -> np.ndarray:
        """(n, n) the state covariance."""
        self._materialise()
        return self._P

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._materialise()
        self._P = np.array(value, dtype=float).reshape(self.n, self.n)

    def _materialise(self) -> None:
        if self._lists is not None:
            x, upper = self._lists
            P = np.empty((6, 6))
            P[_UPPER6] = upper
            P[_LOWER6] = upper
            self._x, self._P, self._lists = np.array(x), P, None

    # ------------------------------------------------------------------ the model

    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(F, Q) over dt seconds."""
        n = self.n
        F = np.eye(n)
        Q = np.zeros((n, n))
        Q[3:6, 3:6] = np.diag(self.q_bias * dt)
        if self.q_rate is not None:
            F[3:6, 6:9] = dt * I3
            Q[3:6, 3:6] += np.diag(self.q_rate * dt**3 / 3.0)
            Q[3:6, 6:9] = Q[6:9, 3:6] = np.diag(self.q_rate * dt**2 / 2.0)
            Q[6:9, 6:9] = np.diag(self.q_rate * dt)
        return F, Q

    def measurement_matrix(self, A: np.ndarray) -> np.ndarray:
        """(3, n) C_k = [A_k, I3, 0]."""
        C = np.zeros((3, self.n))
        C[:, :3] = A
        C[:, 3:6] = I3
        return C

    def measurement_cov(self, a: np.ndarray) -> np.ndarray:
        """(3, 3) R_k = diag(σ²) + [a]ₓ diag(σ_c²) [a]ₓᵀ at the estimate a = x[:3]."""
        S = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        return np.diag(self.r) + S @ np.diag(self.rc) @ S.T

    # ------------------------------------------------------------------ running a block

    def run(
        self,
        y: np.ndarray,
        A: np.ndarray,
        dt: np.ndarray,
        active: np.ndarray,
        gate2: float,
        method: str | None = None,
        tilt: np.ndarray | None = None,
    ) -> StageRun:
        """Filter m samples in order; the state is updated in place.

        Args:
            y: (m, 3) measurements. A: (m, 3, 3) the A_k of each sample.
            dt: (m,) time since the previous sample, s (>= 0).
            tilt: (m,) the angle the tool tilted before each sample, rad (None: no tilt).
            active: (m,) bool, samples that may update (others only predict).
            gate2: a sample with d² > gate2 is refused.
            method: "numba" or "fast" (x = [a, b] only) or "filterpy"; None picks
                "fast" when it applies, else "filterpy".
        """
        if method is None:
            method = "fast" if self.n == 6 else "filterpy"
        tilt = np.zeros(len(y)) if tilt is None else np.asarray(tilt, dtype=float)
        if method in ("fast", "numba"):
            if self.n != 6:
                raise ValueError(f"method: {method!r} needs x = [a, b] (no bias-rate states)")
            if method == "numba":
                return self._run_numba(y, A, dt, tilt, active, gate2)
            return self._run_fast(y, A, dt, tilt, active, gate2)
        if method == "filterpy":
            return self._run_filterpy(y, A, dt, tilt, active, gate2)
        raise ValueError(f"method: unknown {method!r}; known: numba, fast, filterpy")

    def _run_filterpy(self, y, A, dt, tilt, active, gate2) -> StageRun:
        """The reference: filterpy's KalmanFilter does the predict/update bookkeeping."""
        from filterpy.kalman import KalmanFilter

        m, n = len(y), self.n
        kf = KalmanFilter(dim_x=n, dim_z=3)
        kf.x = self.x.reshape(n, 1).copy()
        kf.P = self.P.copy()
        X, D = np.empty((m, n)), np.empty((m, n))
        gated, d2 = np.zeros(m, dtype=bool), np.full(m, np.nan)
        failed = []
        for k in range(m):
            F, Q = self.transition(float(dt[k]))
            self.turn = add_tilt_noise(Q, self.q_tilt, self.r, self.turn, float(tilt[k]), self.tilt_span)
            kf.predict(F=F, Q=Q)
            if active[k]:
                H = self.measurement_matrix(A[k])
                R = self.measurement_cov(kf.x[:3, 0])
                e = y[k].reshape(3, 1) - H @ kf.x
                S = H @ kf.P @ H.T + R
                try:
                    d2[k] = (e.T @ np.linalg.solve(S, e)).item()
                except np.linalg.LinAlgError:  # S singular: predicted only
                    failed.append(k)
                    X[k], D[k] = kf.x[:, 0], np.diag(kf.P)
                    continue
                self.turn = 0.0  # (tested: taken in or refused)
                if not d2[k] <= gate2:  # refused (a NaN is refused too)
                    gated[k] = True
                else:
                    kf.update(y[k].reshape(3, 1), R=R, H=H)
            X[k], D[k] = kf.x[:, 0], np.diag(kf.P)
        self.x, self.P = kf.x[:, 0].copy(), kf.P.copy()
        return StageRun(X, D, gated, d2, self._failed(m, failed))

    def _run_fast(self, y, A, dt, tilt, active, gate2) -> StageRun:
        lists = self._lists
        if lists is None:
            lists = (self._x.tolist(), self._P[_UPPER6].tolist())
        X, D, gated, d2, x, P, failed, self.turn = filter6(
            *lists,
            y.tolist(),
            A.reshape(-1, 9).tolist(),
            dt.tolist(),
            tilt.tolist(),
            active.tolist(),
            self.q_bias.tolist(),
            self.q_tilt.tolist(),
            self.r.tolist(),
            self.rc.tolist(),
            float(gate2),
            self.tilt_span,
            self.turn,
        )
        self._lists = (x, P)
        self._x = self._P = None  # type: ignore[assignment]  # built from the lists when read (_materialise)
        m = len(y)
        return StageRun(
            np.array(X).reshape(m, 6),
            np.array(D).reshape(m, 6),
            np.array(gated, dtype=bool),
            np.array(d2, dtype=float),
            self._failed(m, failed),
        )

    def _run_numba(self, y, A, dt, tilt, active, gate2) -> StageRun:
        """``_run_fast`` compiled (``plugins.estimators.kalman.stage_kernel.filter6``): x and P updated in place, the
        same bits."""
        self._materialise()
        m = len(y)
        X, D, d2 = np.empty((m, 6)), np.empty((m, 6)), np.empty(m)
        gated, failed = np.empty(m, dtype=bool), np.empty(m, dtype=bool)
        contiguous = np.ascontiguousarray
        turn = np.array([self.turn])
        n_failed = kernel.filter6(
            self._x,
            self._P,
            contiguous(y, float),
            contiguous(A, float),
            contiguous(dt, float),
            contiguous(tilt, float),
            contiguous(active, bool),
            self.q_bias,
            self.q_tilt,
            self.r,
            self.rc,
            float(gate2),
            self.tilt_span,
            turn,
            X,
            D,
            gated,
            d2,
            failed,
        )
        self.turn = float(turn[0])
        return StageRun(X, D, gated, d2, self._failed(m, np.flatnonzero(failed)) if n_failed else None)

    def _failed(self, m: int, failed: list[int] | np.ndarray) -> np.ndarray | None:
        """StageRun.failed from the indices of the samples whose update failed (counted in ``self.failed``)."""
        if not failed:
            return None
        self.failed += len(failed)
        mask = np.zeros(m, dtype=bool)
        mask[failed] = True
        return mask


_UPPER6 = np.triu_indices(6)
"""Index of the upper triangle of a 6×6 matrix, row by row (the fast path's P order)."""
_LOWER6 = (_UPPER6[1], _UPPER6[0])


def innovations(y: np.ndarray, A: np.ndarray, x_before: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(m, 3) e_k = y_k − A_k a − b at the state each sample was predicted from.

    That state is the previous row of X (the states after each sample), ``x_before`` (6,)
    for the first; a = x[:3], b = x[3:6].
    """
    X_prev = np.vstack([x_before[None, :6], X[:-1, :6]])
    return y - np.einsum("kij,kj->ki", A, X_prev[:, :3]) - X_prev[:, 3:6]
