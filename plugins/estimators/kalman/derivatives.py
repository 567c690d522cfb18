"""Angular velocity, angular acceleration and linear acceleration of the flange, from the pose stream.

The tool's inertial wrench (``kalman``'s ``inertia`` option) and the time-lag
correction (``time_lag_s``) need the motion's derivatives; the kinematics
stream gives only poses. At each sample k this fits, over the samples of the
last ``window_s`` seconds (k included, so the estimate is causal: no look-ahead,
no added latency), a quadratic through the current pose:

    φ_i = Log(R_BE,kᵀ R_BE,i) ≈ ω_E s_i + ½ α_E s_i²      s_i = t_i − t_k ≤ 0
    p_i − p_k                ≈ v_B s_i + ½ a_B s_i²

(φ_i the rotation vector of sample i relative to sample k, in E at k), by least
squares: a Savitzky–Golay differentiator evaluated at the window's end. For a
motion whose acceleration is constant over the window this is exact (up to
the O(s³) term ω × α of the rotation's exponential); an acceleration that
changes over the window (jerk j) biases α by about j·window_s/2. Interpolated
poses (a 500 Hz robot under a 1 kHz sensor) are piecewise slerps, so the
window should span several kinematics periods: the 20 ms default spans ten at
500 Hz and 2.5 at 125 Hz.

Frames: ω_E, α_E are the angular velocity and acceleration of E relative to
B, expressed in E (rad/s, rad/s²); a_B is the acceleration of E's origin in
B (m/s², gravity not included).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.frames import quat_conjugate, quat_multiply, quat_wxyz_from_matrix


class MotionDerivatives:
    """Causal derivative estimator over a sliding window of past samples.

    Args:
        window_s: the fitting window, s (>= 3 samples are always used once available).

    Call ``update(t_ns, quat_BE, p_BoEo_B)`` with each block in time order.
    """

    def __init__(self, window_s: float = 0.02):
        if not window_s > 0:
            raise ValueError(f"window_s: must be > 0, got {window_s!r}")
        self.window_ns = round(window_s * 1e9)
        self._t = np.zeros(0, dtype=np.int64)
        self._q = np.zeros((0, 4))
        self._p = np.zeros((0, 3))
        self._count: int | None = None  # samples per window, fixed from the first rate seen

    def update(
        self,
        t_ns: np.ndarray,
        quat_BE: np.ndarray | None,
        p_BoEo_B: np.ndarray | None = None,
        R_EB: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Derivatives at each sample of a block.

        Args:
            t_ns: (m,) sample times, ns (increasing).
            quat_BE: (m, 4) [w, x, y, z] orientation of E in B, or None to take it from R_EB.
            p_BoEo_B: (m, 3) positions, m, or None (a_B is zero where a window lacks them).
            R_EB: (m, 3, 3), used when quat_BE is None.

        Returns:
            (w_E (m, 3) rad/s, alpha_E (m, 3) rad/s², a_B (m, 3) m/s²); zeros until three samples
            exist, and at a sample whose pose is not finite (it is also left out of later windows).
        """
        t_ns = np.asarray(t_ns, dtype=np.int64)
        m = len(t_ns)
        if quat_BE is None:
            quat_BE = quat_wxyz_from_matrix(np.asarray(R_EB).transpose(0, 2, 1))
        t = np.concatenate([self._t, t_ns])
        q = np.concatenate([self._q, np.asarray(quat_BE, dtype=float).reshape(m, 4)])
        # a block without positions keeps the history aligned with NaN (no linear acceleration
        # from those samples); positions resume with the next block that has them
        block_p = np.full((m, 3), np.nan) if p_BoEo_B is None else np.asarray(p_BoEo_B, dtype=float).reshape(m, 3)
        p = np.concatenate([self._p, block_p])
        if self._count is None and len(t) >= 2:
            dt = np.median(np.diff(t))
            self._count = int(max(3, min(256, round(self.window_ns / dt) + 1))) if dt > 0 else 3
        count = self._count or 3
        w_E, alpha_E, a_B = np.zeros((m, 3)), np.zeros((m, 3)), np.zeros((m, 3))
        offset = len(t) - m  # index of the block's first sample in t
        k = np.arange(offset, len(t))
        q_ok = np.isfinite(q).all(axis=1)  # a non-finite pose is left out of every window
        usable = (k >= 2) & q_ok[k]  # three samples: a quadratic
        if usable.any():
            k = k[usable]
            lags = np.arange(1, count)  # the past samples of each window
            i = k[:, None] - lags[None, :]  # (n, count-1)
            valid = (i >= 0) & (t[k][:, None] - t[np.maximum(i, 0)] <= self.window_ns)
            valid[:, :2] |= i[:, :2] >= 0  # at least the two previous samples, whatever the spacing
            i = np.maximum(i, 0)
            valid &= q_ok[i]
            phi = _log(quat_multiply(quat_conjugate(q[k])[:, None, :], np.where(valid[..., None], q[i], q[k][:, None])))
            w_E[usable], alpha_E[usable] = _quadratic_fit(t, k, i, valid, phi)
            p_ok = np.isfinite(p).all(axis=1)
            valid_p = valid & p_ok[i] & p_ok[k][:, None]
            if valid_p.any():
                dp = np.where(valid_p[..., None], p[i] - p[k][:, None, :], 0.0)
                a_B[usable] = _quadratic_fit(t, k, i, valid_p, dp)[1]
        keep = max(count - 1, 2)
        self._t, self._q, self._p = t[-keep:], q[-keep:], p[-keep:]
        return w_E, alpha_E, a_B


def _quadratic_fit(t, k, i, valid, y) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y_i ≈ v s_i + ½ a s_i² (s_i = t_i − t_k, s) per window row; (v, a), zeros if too few.

    Args: t (N,) ns; k (n,) window ends; i (n, L) the window's samples; valid (n, L); y (n, L, 3).
    """
    s = (t[i] - t[k][:, None]) * 1e-9 * valid  # 0 where not in the window: no weight
    s2 = 0.5 * s * s
    a11, a12, a22 = (s * s).sum(1), (s * s2).sum(1), (s2 * s2).sum(1)
    det = a11 * a22 - a12 * a12
    ok = det > 1e-30 * np.maximum(a11 * a22, 1e-300)
    inv = np.divide(1.0, det, out=np.zeros_like(det), where=ok)[:, None]
    b1, b2 = np.einsum("nl,nlc->nc", s, y), np.einsum("nl,nlc->nc", s2, y)
    return (a22[:, None] * b1 - a12[:, None] * b2) * inv, (a11[:, None] * b2 - a12[:, None] * b1) * inv


def _log(q: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors (rad) of (..., 4) [w, x, y, z] unit quaternions, angle in [0, π]."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    scale = np.divide(angle, s, out=np.full_like(s, 2.0), where=s > 1e-15)
    return q[..., 1:] * scale
