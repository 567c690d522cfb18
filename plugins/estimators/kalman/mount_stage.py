"""The force stage with the sensor's mount estimated: an error-state EKF of R_SE beside gravity and the bias."""

from __future__ import annotations

import math

import numpy as np

from hapticlab.plugins.estimators.kalman.stage import I3, KalmanStage, StageRun
from hapticlab.plugins.estimators.kalman.stage_kernel import add_tilt_noise


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
