"""The ``kalman`` estimator's ``inertia`` option per sample, compiled: motion derivatives and inertial force.

``windows`` is the sliding-window fit of ``plugins.estimators.kalman.derivatives.MotionDerivatives`` (the numpy
reference, which stays callable: ``kernel = "numpy"``) at each sample k of a block:

    φ_i = Log(q_kᵀ ⊗ q_i) ≈ ω_E s_i + ½ α_E s_i²,   p_i − p_k ≈ v_B s_i + ½ a_B s_i²   (s_i = t_i − t_k ≤ 0)

over the past samples of the window (at least the two previous ones), least squares of
the 2×2 normal equations. ``inertial_force`` is ``KalmanEstimator._inertial_force``:
−m (a_S + α_S × c + ω_S × (ω_S × c)), N; ``inertial_before`` the same at one sample of the compiled
cascade, from the states before it (a block then filters as its samples one at a time).

Not bit-for-bit the numpy path: numpy sums a window's 20 terms pairwise (8 accumulators) and
through ``einsum``, the kernel in order; the derivatives agree to ~1e-13 relative, and the
filter's outputs then to ~1e-12 N (tests/plugins/estimators/kalman/test_kernels.py).

Compiled the first time, then loaded from the ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hapticlab.core.frames import GRAVITY_M_S2
from hapticlab.plugins.estimators.kalman.derivatives import MotionDerivatives
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_FORCE_SEEN, ADAPT_TORQUE_SEEN


@njit(cache=True)
def quat_BE_from_R_EB(R_EB, out):
    """out (m, 4): [w, x, y, z] of R_BE = R_EBᵀ, w >= 0 (``core.frames.quat_wxyz_from_matrix``, Shepperd's
    method, transcribed: the same bits)."""
    for k in range(R_EB.shape[0]):
        R = R_EB[k].T
        trace = R[0, 0] + R[1, 1] + R[2, 2]
        K0 = 1.0 + trace
        K1 = (1.0 - trace) + 2.0 * R[0, 0]
        K2 = (1.0 - trace) + 2.0 * R[1, 1]
        K3 = (1.0 - trace) + 2.0 * R[2, 2]
        best, largest = 0, K0  # the first largest diagonal entry (numpy's argmax)
        if K1 > largest:
            best, largest = 1, K1
        if K2 > largest:
            best, largest = 2, K2
        if K3 > largest:
            best = 3
        v0, v1, v2 = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
        s01, s02, s12 = R[0, 1] + R[1, 0], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1]
        if best == 0:
            q0, q1, q2, q3 = K0, v0, v1, v2
        elif best == 1:
            q0, q1, q2, q3 = v0, K1, s01, s02
        elif best == 2:
            q0, q1, q2, q3 = v1, s01, K2, s12
        else:
            q0, q1, q2, q3 = v2, s02, s12, K3
        scale = (-1.0 if q0 < 0 else 1.0) / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = q0 * scale, q1 * scale, q2 * scale, q3 * scale


@njit(cache=True)
def _log_relative(q, k, i, out):
    """out (3,) = Log(conj(q_k) ⊗ q_i), rad (``plugins.estimators.kalman.derivatives._log`` of ``quat_multiply``)."""
    aw, ax, ay, az = q[k, 0], -q[k, 1], -q[k, 2], -q[k, 3]
    bw, bx, by, bz = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 * math.atan2(s, w) / s if s > 1e-15 else 2.0
    out[0], out[1], out[2] = x * scale, y * scale, z * scale


@njit(cache=True)
def _fit(a11, a12, a22, b1, b2, v, a):
    """v, a (3,) from the normal equations of y ≈ v s + ½ a s² (zeros when they are singular)."""
    det = a11 * a22 - a12 * a12
    inv = 1.0 / det if det > 1e-30 * max(a11 * a22, 1e-300) else 0.0
    for c in range(3):
        v[c] = (a22 * b1[c] - a12 * b2[c]) * inv
        a[c] = (a11 * b2[c] - a12 * b1[c]) * inv


@njit(cache=True)
def windows(t, q, p, offset, count, window_ns, w_E, alpha_E, a_B, work):
    """Derivatives at samples offset..N−1 of the history (``MotionDerivatives.update``'s fit).

    Args:
        t: (N,) int64 ns. q: (N, 4) [w, x, y, z] of E in B. p: (N, 3) positions, m (NaN: none).
        offset: the block's first sample. count: samples per window. window_ns: its length, ns.
        w_E, alpha_E, a_B: (N − offset, 3) out, rad/s, rad/s², m/s² (zeros where not computed).
        work: (6, 3) scratch.
    """
    n = t.shape[0]
    phi, b1, b2, c1, c2, v = work[0], work[1], work[2], work[3], work[4], work[5]
    for k in range(offset, n):
        j = k - offset
        for c in range(3):
            w_E[j, c] = 0.0
            alpha_E[j, c] = 0.0
            a_B[j, c] = 0.0
        q_ok = math.isfinite(q[k, 0]) and math.isfinite(q[k, 1]) and math.isfinite(q[k, 2]) and math.isfinite(q[k, 3])
        if k < 2 or not q_ok:
            continue
        p_k = math.isfinite(p[k, 0]) and math.isfinite(p[k, 1]) and math.isfinite(p[k, 2])
        a11 = a12 = a22 = 0.0
        e11 = e12 = e22 = 0.0
        for c in range(3):
            b1[c] = b2[c] = c1[c] = c2[c] = 0.0
        for lag in range(1, count):
            i = k - lag
            if i < 0:
                break
            valid = lag <= 2 or t[k] - t[i] <= window_ns
            valid = (
                valid
                and math.isfinite(q[i, 0])
                and math.isfinite(q[i, 1])
                and math.isfinite(q[i, 2])
                and math.isfinite(q[i, 3])
            )
            if not valid:
                continue
            s = (t[i] - t[k]) * 1e-9
            s2 = 0.5 * s * s
            a11 += s * s
            a12 += s * s2
            a22 += s2 * s2
            _log_relative(q, k, i, phi)
            for c in range(3):
                b1[c] += s * phi[c]
                b2[c] += s2 * phi[c]
            if p_k and math.isfinite(p[i, 0]) and math.isfinite(p[i, 1]) and math.isfinite(p[i, 2]):
                e11 += s * s
                e12 += s * s2
                e22 += s2 * s2
                for c in range(3):
                    d = p[i, c] - p[k, c]
                    c1[c] += s * d
                    c2[c] += s2 * d
        _fit(a11, a12, a22, b1, b2, w_E[j], alpha_E[j])
        _fit(e11, e12, e22, c1, c2, v, a_B[j])


@njit(cache=True)
def inertial_force(R_SE, R_SB, w_E, alpha_E, a_B, mass, cog_S, out):
    """out (m, 3) = −mass (a_S + α_S × c + ω_S × (ω_S × c)), N; ω_S = R_SE ω_E, α_S = R_SE α_E, a_S = R_SB a_B.

    Args: R_SE (3, 3); R_SB (m, 3, 3); w_E, alpha_E (m, 3) rad/s, rad/s²; a_B (m, 3) m/s²; mass kg;
    cog_S (3,) m.
    """
    for k in range(w_E.shape[0]):
        _inertial_at(R_SE, R_SB[k], w_E[k], alpha_E[k], a_B[k], mass, cog_S[0], cog_S[1], cog_S[2], out[k])


@njit(cache=True)
def _inertial_at(R_SE, R_SB, w, alpha, a, mass, cx, cy, cz, out):
    """``inertial_force`` at one sample: R_SB (3, 3); w, alpha, a (3,) in E, E and B; out (3,) N."""
    wx = w[0] * R_SE[0, 0] + w[1] * R_SE[0, 1] + w[2] * R_SE[0, 2]
    wy = w[0] * R_SE[1, 0] + w[1] * R_SE[1, 1] + w[2] * R_SE[1, 2]
    wz = w[0] * R_SE[2, 0] + w[1] * R_SE[2, 1] + w[2] * R_SE[2, 2]
    ax = alpha[0] * R_SE[0, 0] + alpha[1] * R_SE[0, 1] + alpha[2] * R_SE[0, 2]
    ay = alpha[0] * R_SE[1, 0] + alpha[1] * R_SE[1, 1] + alpha[2] * R_SE[1, 2]
    az = alpha[0] * R_SE[2, 0] + alpha[1] * R_SE[2, 1] + alpha[2] * R_SE[2, 2]
    sx = R_SB[0, 0] * a[0] + R_SB[0, 1] * a[1] + R_SB[0, 2] * a[2]
    sy = R_SB[1, 0] * a[0] + R_SB[1, 1] * a[1] + R_SB[1, 2] * a[2]
    sz = R_SB[2, 0] * a[0] + R_SB[2, 1] * a[1] + R_SB[2, 2] * a[2]
    ux, uy, uz = wy * cz - wz * cy, wz * cx - wx * cz, wx * cy - wy * cx  # ω × c
    out[0] = -mass * (sx + (ay * cz - az * cy) + (wy * uz - wz * uy))
    out[1] = -mass * (sy + (az * cx - ax * cz) + (wz * ux - wx * uz))
    out[2] = -mass * (sz + (ax * cy - ay * cx) + (wx * uy - wy * ux))


@njit(cache=True)
def inertial_before(adapt, known, x_f, x_t, R_SE, A, mount, motion, force, y, inertial, R_SB):
    """One sample's inertial force from the states before it, inside ``cascade_kernel.kalman_cascade``: what
    ``KalmanEstimator._prepare`` gives a block of one sample, so a block filters as its samples one by one.

    Zero until the force stage has settled (``adapt[ADAPT_FORCE_SEEN]``) or ``known[0]`` (a warm start's);
    the mass |x_f[:3]| / g, the centre of mass x_t[:3] once the torque stage has settled (or ``known[1]``),
    else the sensor origin. Args: R_SE (3, 3) the mount as it is; A (3, 3) the force stage's A_f row (R_EB
    when ``mount``: R_SB = R_SE R_EB; else R_SB); motion (9,) [ω_E rad/s, α_E rad/s², a_B m/s²]; force (3,) N.
    Out: y (3,) = force − inertial, inertial (3,) N; R_SB (3, 3) scratch.
    """
    if adapt[ADAPT_FORCE_SEEN] == 0.0 and known[0] == 0.0:
        for i in range(3):
            inertial[i], y[i] = 0.0, force[i]
        return
    mass = math.sqrt(x_f[0] * x_f[0] + x_f[1] * x_f[1] + x_f[2] * x_f[2]) / GRAVITY_M_S2
    cog_known = adapt[ADAPT_TORQUE_SEEN] != 0.0 or known[1] != 0.0
    cx, cy, cz = (x_t[0], x_t[1], x_t[2]) if cog_known else (0.0, 0.0, 0.0)
    if mount:
        for i in range(3):
            for j in range(3):
                R_SB[i, j] = R_SE[i, 0] * A[0, j] + R_SE[i, 1] * A[1, j] + R_SE[i, 2] * A[2, j]
    else:
        R_SB[:, :] = A
    _inertial_at(R_SE, R_SB, motion[0:3], motion[3:6], motion[6:9], mass, cx, cy, cz, inertial)
    for i in range(3):
        y[i] = force[i] - inertial[i]


class CompiledMotionDerivatives(MotionDerivatives):
    """``MotionDerivatives`` with the windows' fit compiled (``windows``); the same history and interface."""

    def __init__(self, window_s: float = 0.02):
        super().__init__(window_s)
        self._work = np.empty((6, 3))

    def update(self, t_ns, quat_BE, p_BoEo_B=None, R_EB=None):
        """``MotionDerivatives.update``: (w_E, alpha_E, a_B), each (m, 3)."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        m = len(t_ns)
        if quat_BE is None:
            quat_BE = np.empty((m, 4))
            quat_BE_from_R_EB(np.ascontiguousarray(R_EB, float), quat_BE)
        t = np.concatenate([self._t, t_ns])
        q = np.concatenate([self._q, np.asarray(quat_BE, dtype=float).reshape(m, 4)])
        block_p = np.full((m, 3), np.nan) if p_BoEo_B is None else np.asarray(p_BoEo_B, float).reshape(m, 3)
        p = np.concatenate([self._p, block_p])
        if self._count is None and len(t) >= 2:
            dt = np.median(np.diff(t))
            self._count = int(max(3, min(256, round(self.window_ns / dt) + 1))) if dt > 0 else 3
        count = self._count or 3
        w_E, alpha_E, a_B = np.empty((m, 3)), np.empty((m, 3)), np.empty((m, 3))
        windows(t, q, p, len(t) - m, count, self.window_ns, w_E, alpha_E, a_B, self._work)
        keep = max(count - 1, 2)
        self._t, self._q, self._p = t[-keep:], q[-keep:], p[-keep:]
        return w_E, alpha_E, a_B


def warm_up() -> None:
    """Compile ``windows`` and ``inertial_force`` (or load them from the cache) by running each once."""
    d = CompiledMotionDerivatives(0.02)
    q = np.array([[1.0, 0.0, 0.0, 0.0]] * 4)
    w, al, a = d.update(np.arange(4, dtype=np.int64) * 1_000_000, q, np.zeros((4, 3)))
    inertial_force(
        np.eye(3), np.broadcast_to(np.eye(3), (4, 3, 3)).copy(), w, al, a, 1.0, np.zeros(3), np.empty((4, 3))
    )
