"""Kalman filter for one stage of the paper's cascade, with drifting sensor bias.

Measurement model of a stage (the same shape as ``plugins.estimators.rls.information_form``):

    y_k = A_k a + b_k + v_k,      v_k ~ N(0, R_k)

* force stage: y = force_S, A_k = R_EB, a = gravity_force_B, b = bias_force_S;
* torque stage: y = torque_S, A_k = -skew(force_S - bias_force_S), a = cog_S,
  b = bias_torque_S.

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
sample: at 1 kHz a tool turning 19°/s with q_θ = (0.1 N/√rad)² and σ = 0.12 N
is followed over 0.022 rad, 65 ms, fast enough to take in the first newtons of
a contact's ramp before the gate refuses it. The cap keeps the tilt walk's own
span at s or more whatever the sample rate and the turn rate (the walk over
time, on top, follows on its own); the errors the walk stands for change
smoothly with the tilt, so a finer span follows noise and contacts, not them.
Over samples the stage does not test (a sensor status, a stale pose) the turn
adds up, and the whole turn Θ adds min(q_θ·Θ, σ²·(Θ/s)²), however finely it was
sampled (``kernels.kalman_stage.add_tilt_noise``, which every path runs: compiled, or as Python in the
filterpy reference and the mount's EKF; the unrolled ``_filter6`` writes it out).

Measurement noise R_k: the sensor's per-axis variance, diag(σ²). The torque
stage's A_k is built from the *measured* force, whose noise enters the torque
equation through p × Δf, so its R_k adds [p]ₓ diag(σ_f²) [p]ₓᵀ at the current
estimate of p (for a 4 cm centre of gravity and 0.12 N this is
0.005 N·m per axis, half the torque noise itself).

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
  reference, ~35 µs per sample per stage (~45 with bias-rate states); it is
  also what runs with ``bias_rate`` under ``kernel = "numpy"`` (the compiled cascade
  has its own step for them, ``plugins.estimators.kalman.stage_kernel.stage_step_rate``).
* ``method="numba"`` (x = [a, b]): ``_filter6`` compiled (``plugins.estimators.kalman.stage_kernel``),
  the same bits; the ``kalman`` estimator's default (``kernel = "numba"``).
* ``method="fast"`` (x = [a, b], the default model): the same filter
  specialised to C = [A, I3] and a symmetric 6×6 P (21 numbers), unrolled in
  plain Python floats, so no numpy call happens per sample; S is factored as
  L·diag(d)·Lᵀ, which makes the update three decorrelated scalar updates and
  d² a sum of positive terms. ~3 µs per sample per stage. (A closed-form
  adjugate inverse of S lost up to 1e-5 N against the reference while P still
  held a wide prior (tried with 50 N); the LDLᵀ form stays within 1e-11.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hapticlab.plugins.estimators.kalman import stage_kernel as kernel

I3 = np.eye(3)
add_tilt_noise = kernel.add_tilt_noise.py_func
"""The tilt walk's addition to the bias's variance, run as Python here (the compiled stage runs it compiled)."""

TILT_SPAN = 0.15
"""rad: the ``kalman`` estimator's default span of the tilt walk (``add_tilt_noise``), half the window of turn
over which ``plugins.estimators.kalman.tilt_walk_kernel`` measures it: a walk learnt at that scale says nothing finer. On the
lwr4_2013_06_13 log (1 Hz) the learnt walk still leaves no row judged a contact (5 at 0.3 rad), its RMS
0.335 of the batch fit instead of 0.324 without a span."""


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
        prior_std,
        bias_rw,
        noise,
        cross_noise=(0.0, 0.0, 0.0),
        bias_rate_rw=None,
        bias_tilt_rw=(0.0, 0.0, 0.0),
        tilt_span=0.0,
    ):
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
        X, D, gated, d2, x, P, failed, self.turn = _filter6(
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
        self._x = self._P = None  # built from the lists when read
        m = len(y)
        return StageRun(
            np.array(X).reshape(m, 6),
            np.array(D).reshape(m, 6),
            np.array(gated, dtype=bool),
            np.array(d2, dtype=float),
            self._failed(m, failed),
        )

    def _run_numba(self, y, A, dt, tilt, active, gate2) -> StageRun:
        """``_run_fast`` compiled (``plugins.estimators.kalman.stage_kernel.filter6``): x and P updated in place, the same bits."""
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

    def _failed(self, m: int, failed: list[int]) -> np.ndarray | None:
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


def _filter6(x, P, Y, A, DT, TILT, ACTIVE, q, qt, r, rc, gate2, span, turn):
    """The stage filter for x = [a, b], C = [A, I3], in plain Python floats.

    P is the upper triangle of the symmetric 6×6 covariance, row by row
    (21 numbers). The arithmetic is the textbook one: P⁻ = P + Q; PCᵀ; S = C PCᵀ + R;
    e = y − C x⁻; S = L·diag(d)·Lᵀ; d² = eᵀ S⁻¹ e; if accepted,
    x = x⁻ + PCᵀ S⁻¹ e and P = P⁻ − PCᵀ S⁻¹ (PCᵀ)ᵀ, evaluated through
    U = PCᵀ L⁻ᵀ as x⁻ + U diag(d)⁻¹ L⁻¹ e and P⁻ − U diag(d)⁻¹ Uᵀ.
    """
    x0, x1, x2, x3, x4, x5 = x
    (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25, p33, p34, p35, p44, p45, p55) = P
    q0, q1, q2 = q
    qt0, qt1, qt2 = qt
    r0, r1, r2 = r
    rc0, rc1, rc2 = rc
    cross = rc0 != 0.0 or rc1 != 0.0 or rc2 != 0.0
    nan = float("nan")
    X, D, G, E, FAILED = [], [], [], [], []
    for k in range(len(Y)):
        tilt = TILT[k]
        if tilt != 0.0:  # the tilt walk (kernel.add_tilt_noise; turn: since the stage last tested a sample)
            after = turn + tilt
            if span > 0.0:
                s0, s1 = (turn / span) ** 2, (after / span) ** 2
                p33 += min(qt0 * after, r0 * s1) - min(qt0 * turn, r0 * s0)
                p44 += min(qt1 * after, r1 * s1) - min(qt1 * turn, r1 * s0)
                p55 += min(qt2 * after, r2 * s1) - min(qt2 * turn, r2 * s0)
            else:
                p33 += qt0 * tilt
                p44 += qt1 * tilt
                p55 += qt2 * tilt
            turn = after
        dt = DT[k]
        if dt != 0.0:
            p33 += q0 * dt
            p44 += q1 * dt
            p55 += q2 * dt
        if ACTIVE[k]:
            a00, a01, a02, a10, a11, a12, a20, a21, a22 = A[k]
            y0, y1, y2 = Y[k]
            # PCᵀ: column l is P[:, :3] · A[l] + P[:, 3 + l]
            c00 = p00 * a00 + p01 * a01 + p02 * a02 + p03
            c10 = p01 * a00 + p11 * a01 + p12 * a02 + p13
            c20 = p02 * a00 + p12 * a01 + p22 * a02 + p23
            c30 = p03 * a00 + p13 * a01 + p23 * a02 + p33
            c40 = p04 * a00 + p14 * a01 + p24 * a02 + p34
            c50 = p05 * a00 + p15 * a01 + p25 * a02 + p35
            c01 = p00 * a10 + p01 * a11 + p02 * a12 + p04
            c11 = p01 * a10 + p11 * a11 + p12 * a12 + p14
            c21 = p02 * a10 + p12 * a11 + p22 * a12 + p24
            c31 = p03 * a10 + p13 * a11 + p23 * a12 + p34
            c41 = p04 * a10 + p14 * a11 + p24 * a12 + p44
            c51 = p05 * a10 + p15 * a11 + p25 * a12 + p45
            c02 = p00 * a20 + p01 * a21 + p02 * a22 + p05
            c12 = p01 * a20 + p11 * a21 + p12 * a22 + p15
            c22 = p02 * a20 + p12 * a21 + p22 * a22 + p25
            c32 = p03 * a20 + p13 * a21 + p23 * a22 + p35
            c42 = p04 * a20 + p14 * a21 + p24 * a22 + p45
            c52 = p05 * a20 + p15 * a21 + p25 * a22 + p55
            # S = C PCᵀ + R
            s00 = a00 * c00 + a01 * c10 + a02 * c20 + c30 + r0
            s01 = a00 * c01 + a01 * c11 + a02 * c21 + c31
            s02 = a00 * c02 + a01 * c12 + a02 * c22 + c32
            s11 = a10 * c01 + a11 * c11 + a12 * c21 + c41 + r1
            s12 = a10 * c02 + a11 * c12 + a12 * c22 + c42
            s22 = a20 * c02 + a21 * c12 + a22 * c22 + c52 + r2
            if cross:  # [a]ₓ diag(rc) [a]ₓᵀ at the prior estimate of a
                s00 += rc1 * x2 * x2 + rc2 * x1 * x1
                s11 += rc0 * x2 * x2 + rc2 * x0 * x0
                s22 += rc0 * x1 * x1 + rc1 * x0 * x0
                s01 -= rc2 * x0 * x1
                s02 -= rc1 * x0 * x2
                s12 -= rc0 * x1 * x2
            e0 = y0 - (a00 * x0 + a01 * x1 + a02 * x2 + x3)
            e1 = y1 - (a10 * x0 + a11 * x1 + a12 * x2 + x4)
            e2 = y2 - (a20 * x0 + a21 * x1 + a22 * x2 + x5)
            # S = L·diag(d)·Lᵀ (LDLᵀ, L unit lower triangular): d² and the update
            # without forming S⁻¹, as three decorrelated scalar updates
            try:
                d0 = s00
                l10 = s01 / d0
                l20 = s02 / d0
                d1 = s11 - l10 * s01
                t = s12 - l20 * s01
                l21 = t / d1
                d2_ = s22 - l20 * s02 - l21 * t
                z1 = e1 - l10 * e0  # z = L⁻¹ e
                z2 = e2 - l20 * e0 - l21 * z1
                z0 = e0 / d0  # then D⁻¹ z
                z1 /= d1
                z2 /= d2_
            except ZeroDivisionError:
                d0 = 0.0
            if not (d0 > 0.0 and d1 > 0.0 and d2_ > 0.0):  # S not numerically positive definite: no update
                FAILED.append(k)
                G.append(False)
                E.append(nan)
            elif not (d2 := z0 * z0 * d0 + z1 * z1 * d1 + z2 * z2 * d2_) <= gate2:  # eᵀ S⁻¹ e; refused (NaN too)
                E.append(d2)
                G.append(True)
                turn = 0.0  # tested
            else:
                E.append(d2)
                G.append(False)
                turn = 0.0  # tested
                # U = PCᵀ L⁻ᵀ (columns u0, u1, u2); x += U D⁻¹ L⁻¹ e; P -= U D⁻¹ Uᵀ
                u10 = c01 - l10 * c00
                u11 = c11 - l10 * c10
                u12 = c21 - l10 * c20
                u13 = c31 - l10 * c30
                u14 = c41 - l10 * c40
                u15 = c51 - l10 * c50
                u20 = c02 - l20 * c00 - l21 * u10
                u21 = c12 - l20 * c10 - l21 * u11
                u22 = c22 - l20 * c20 - l21 * u12
                u23 = c32 - l20 * c30 - l21 * u13
                u24 = c42 - l20 * c40 - l21 * u14
                u25 = c52 - l20 * c50 - l21 * u15
                x0 += c00 * z0 + u10 * z1 + u20 * z2
                x1 += c10 * z0 + u11 * z1 + u21 * z2
                x2 += c20 * z0 + u12 * z1 + u22 * z2
                x3 += c30 * z0 + u13 * z1 + u23 * z2
                x4 += c40 * z0 + u14 * z1 + u24 * z2
                x5 += c50 * z0 + u15 * z1 + u25 * z2
                g0 = c00 / d0
                g1 = u10 / d1
                g2 = u20 / d2_
                p00 -= g0 * c00 + g1 * u10 + g2 * u20
                p01 -= g0 * c10 + g1 * u11 + g2 * u21
                p02 -= g0 * c20 + g1 * u12 + g2 * u22
                p03 -= g0 * c30 + g1 * u13 + g2 * u23
                p04 -= g0 * c40 + g1 * u14 + g2 * u24
                p05 -= g0 * c50 + g1 * u15 + g2 * u25
                g0 = c10 / d0
                g1 = u11 / d1
                g2 = u21 / d2_
                p11 -= g0 * c10 + g1 * u11 + g2 * u21
                p12 -= g0 * c20 + g1 * u12 + g2 * u22
                p13 -= g0 * c30 + g1 * u13 + g2 * u23
                p14 -= g0 * c40 + g1 * u14 + g2 * u24
                p15 -= g0 * c50 + g1 * u15 + g2 * u25
                g0 = c20 / d0
                g1 = u12 / d1
                g2 = u22 / d2_
                p22 -= g0 * c20 + g1 * u12 + g2 * u22
                p23 -= g0 * c30 + g1 * u13 + g2 * u23
                p24 -= g0 * c40 + g1 * u14 + g2 * u24
                p25 -= g0 * c50 + g1 * u15 + g2 * u25
                g0 = c30 / d0
                g1 = u13 / d1
                g2 = u23 / d2_
                p33 -= g0 * c30 + g1 * u13 + g2 * u23
                p34 -= g0 * c40 + g1 * u14 + g2 * u24
                p35 -= g0 * c50 + g1 * u15 + g2 * u25
                g0 = c40 / d0
                g1 = u14 / d1
                g2 = u24 / d2_
                p44 -= g0 * c40 + g1 * u14 + g2 * u24
                p45 -= g0 * c50 + g1 * u15 + g2 * u25
                p55 -= c50 * c50 / d0 + u15 * u15 / d1 + u25 * u25 / d2_
        else:
            G.append(False)
            E.append(nan)
        X += (x0, x1, x2, x3, x4, x5)
        D += (p00, p11, p22, p33, p44, p55)
    P = [p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25, p33, p34, p35, p44, p45, p55]
    return X, D, G, E, [x0, x1, x2, x3, x4, x5], P, FAILED, turn


class MountStage(KalmanStage):
    """The force stage with the sensor's mount rotation R_SE estimated too (an error-state EKF).

    Model: y_k = R_SE R_EB,k a + b + v_k, with a = gravity_force_B and the mount
    R_SE = R̂ Exp(θ) kept as a nominal rotation R̂ and a small-angle error θ (3
    states, rad, appended to x: x = [a, b, (ḃ), θ]). Linearised at θ = 0,

        C_k = [R̂ R_EB,k,  I3,  (0),  −R̂ [R_EB,k a]ₓ]

    and because θ is zero before every update, C_k x equals the nonlinear
    prediction R̂ R_EB,k a + b exactly, so the update is the linear Kalman update
    (Joseph form) with this C_k. After each accepted update θ is folded into
    the nominal rotation (R̂ ← R̂ Exp(θ), θ ← 0; the "multiplicative" EKF, P kept
    to first order). θ is constant (no process noise: a mount does not move).
    Until a is known the θ columns are near zero and θ keeps its prior: the
    mount is learnt once the weight is.

    The transition is KalmanStage's (it touches the bias and rate blocks only,
    so θ is carried unchanged).

    Args (beyond KalmanStage's): R_SE: (3, 3) the initial nominal mount; mount_prior_std: prior std of θ, rad.

    Attributes: R_SE: (3, 3) the current estimate of the mount rotation.
    """

    def __init__(
        self,
        prior_std,
        bias_rw,
        noise,
        R_SE,
        mount_prior_std,
        bias_rate_rw=None,
        activate_std=0.5,
        bias_tilt_rw=(0.0, 0.0, 0.0),
        tilt_span=0.0,
    ):
        base = 6 if bias_rate_rw is None else 9
        super().__init__(
            np.asarray(prior_std, dtype=float)[:base],
            bias_rw,
            noise,
            bias_rate_rw=bias_rate_rw,
            bias_tilt_rw=bias_tilt_rw,
            tilt_span=tilt_span,
        )
        self.n = base + 3
        x, P = np.zeros(self.n), np.zeros((self.n, self.n))
        P[:base, :base] = np.diag(np.asarray(prior_std, dtype=float)[:base] ** 2)
        P[base:, base:] = np.eye(3) * float(mount_prior_std) ** 2
        self._x, self._P = x, P
        self.R_SE = np.array(R_SE, dtype=float)
        self.activate_var = float(activate_std) ** 2

    def run(
        self,
        y: np.ndarray,
        R_EB: np.ndarray,
        dt: np.ndarray,
        active: np.ndarray,
        gate2: float,
        method: str | None = None,
        tilt: np.ndarray | None = None,
    ) -> StageRun:
        """Filter m samples in order (numpy, one sample at a time); x, P and R_SE are updated in place.

        Same arguments as KalmanStage.run, except that R_EB (m, 3, 3) is the robot's
        orientation alone: the stage applies its own mount estimate. ``method`` is ignored.
        """
        m, n = len(y), self.n
        x, P, R_SE = self.x.copy(), self.P.copy(), self.R_SE.copy()
        R = np.diag(self.r)
        X, D = np.empty((m, n)), np.empty((m, n))
        gated, d2 = np.zeros(m, dtype=bool), np.full(m, np.nan)
        failed = []
        cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        C = np.zeros((3, n))
        C[:, 3:6] = I3
        In = np.eye(n)
        for k in range(m):
            if tilt is not None and tilt[k] != 0.0:  # the tilt walk
                self.turn = add_tilt_noise(P, self.q_tilt, self.r, self.turn, float(tilt[k]), self.tilt_span)
            step = float(dt[k])
            if step != 0.0:
                if step not in cache:
                    cache[step] = self.transition(step)
                F, Q = cache[step]
                x = F @ x
                P = F @ P @ F.T + Q
            if active[k]:
                v_E = R_EB[k] @ x[:3]
                C[:, :3] = R_SE @ R_EB[k]
                if max(P[0, 0], P[1, 1], P[2, 2]) > self.activate_var:
                    C[:, n - 3 :] = 0.0  # a not yet known: θ waits (see the class docstring)
                else:
                    C[:, n - 3 :] = -R_SE @ np.array(
                        [[0.0, -v_E[2], v_E[1]], [v_E[2], 0.0, -v_E[0]], [-v_E[1], v_E[0], 0.0]]
                    )
                e = y[k] - C[:, :3] @ x[:3] - x[3:6]
                PCt = P @ C.T
                S = C @ PCt + R
                try:
                    d2[k] = float(e @ np.linalg.solve(S, e))
                except np.linalg.LinAlgError:  # S singular: predicted only
                    failed.append(k)
                    X[k], D[k] = x, np.diag(P)
                    continue
                self.turn = 0.0  # (tested: taken in or refused)
                if not d2[k] <= gate2:
                    gated[k] = True
                else:
                    K = np.linalg.solve(S, PCt.T).T  # S symmetric: K = P Cᵀ S⁻¹
                    x = x + K @ e
                    IKC = In - K @ C
                    P = IKC @ P @ IKC.T + K @ R @ K.T
                    P = 0.5 * (P + P.T)
                    R_SE = R_SE @ _exp_so3(x[n - 3 :])
                    x[n - 3 :] = 0.0
            X[k], D[k] = x, np.diag(P)
        self.x, self.P, self.R_SE = x, P, R_SE
        return StageRun(X, D, gated, d2, self._failed(m, failed))


def _exp_so3(theta: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a rotation vector theta (3,), rad (Rodrigues)."""
    angle = float(np.linalg.norm(theta))
    K = np.array([[0.0, -theta[2], theta[1]], [theta[2], 0.0, -theta[0]], [-theta[1], theta[0], 0.0]])
    if angle < 1e-8:
        return I3 + K + 0.5 * K @ K
    return I3 + math.sin(angle) / angle * K + (1.0 - math.cos(angle)) / angle**2 * K @ K


def innovations(y: np.ndarray, A: np.ndarray, x_before: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(m, 3) e_k = y_k − A_k a − b at the state each sample was predicted from.

    That state is the previous row of X (the states after each sample), ``x_before`` (6,)
    for the first; a = x[:3], b = x[3:6].
    """
    X_prev = np.vstack([x_before[None, :6], X[:-1, :6]])
    return y - np.einsum("kij,kj->ki", A, X_prev[:, :3]) - X_prev[:, 3:6]
