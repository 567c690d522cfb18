"""The live aligner's per-block work, compiled: each wrench sample's orientation (and position) from the poses.

The compiled twin of ``core.aligner.orientation_at`` + ``position_at`` +
``frames.matrix_from_quat_wxyz`` (the numpy reference, which the offline stream
and the tests keep using). For each sample time t (ns) and the buffered poses
(t_j, q_j, p_j), j = 0 … P−1:

* t_0 ≤ t ≤ t_{P−1}: q = slerp(q_i, q_{i+1}, u), u = (t − t_i)/(t_{i+1} − t_i),
  the shorter way round; p linear between p_i and p_{i+1};
* t > t_{P−1}: q = exp(ω_B·Δt) ⊗ q_{P−1} with ω_B from the last two poses and
  Δt = min(t − t_{P−1}, period) (constant angular velocity for at most one
  kinematics period), p likewise at the last velocity; stale beyond a period;
* t < t_0: q_0 and p_0, stale.

R_EB = R(q)ᵀ. Not bit-for-bit the numpy path (libm's sin/arccos and the order of
the norm's sum): tests/core/test_aligner_kernel.py holds them to 1e-12.

Compiled the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def _slerp(q0: np.ndarray, q1: np.ndarray, u: float, out: np.ndarray) -> None:
    dot = q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3]
    sign = -1.0 if dot < 0.0 else 1.0  # the shorter way round
    c = min(abs(dot), 1.0)
    theta = math.acos(c)
    s = math.sin(theta)
    if s < 1e-9:
        w0, w1 = 1.0 - u, u
    else:
        w0, w1 = math.sin((1.0 - u) * theta) / s, math.sin(u * theta) / s
    norm = 0.0
    for k in range(4):
        out[k] = w0 * q0[k] + w1 * sign * q1[k]
        norm += out[k] * out[k]
    norm = math.sqrt(norm)
    for k in range(4):
        out[k] /= norm


@njit(cache=True)
def _multiply(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """out = a ⊗ b (Hamilton, [w, x, y, z])."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@njit(cache=True)
def align_block(
    t_ns: np.ndarray,
    pose_t_ns: np.ndarray,
    quat_BE: np.ndarray,
    p_BoEo_B: np.ndarray,
    period_ns: int,
    out_quat_BE: np.ndarray,
    out_R_EB: np.ndarray,
    out_p_BoEo_B: np.ndarray,
    out_stale: np.ndarray,
) -> None:
    """Orientation (and position) of E in B at each sample time, in place.

    Args:
        t_ns: (n,) int64 sample times, ns.
        pose_t_ns: (P,) int64 increasing pose times, ns (P ≥ 1).
        quat_BE: (P, 4) [w, x, y, z] orientations at those times.
        p_BoEo_B: (P, 3) positions, m, or a (0, 3) array when the poses carry none.
        period_ns: the kinematics period, ns: the longest extrapolation.
        out_quat_BE: (n, 4) out. out_R_EB: (n, 3, 3) out: R_BEᵀ.
        out_p_BoEo_B: (n, 3) out (left alone without positions). out_stale: (n,) bool out.
    """
    P = len(pose_t_ns)
    first, last = pose_t_ns[0], pose_t_ns[P - 1]
    with_p = p_BoEo_B.shape[0] == P
    # the last measured velocities, for the extrapolation after the newest pose
    moving = P >= 2 and last > pose_t_ns[P - 2]
    w_B = np.zeros(3)
    v_B = np.zeros(3)
    step = np.empty(4)
    q_conj = np.empty(4)
    if moving:
        dt_last = (last - pose_t_ns[P - 2]) * 1e-9
        q_conj[0] = quat_BE[P - 2, 0]
        for k in range(1, 4):
            q_conj[k] = -quat_BE[P - 2, k]
        _multiply(quat_BE[P - 1], q_conj, step)
        if step[0] < 0.0:
            for k in range(4):
                step[k] = -step[k]
        s = math.sqrt(step[1] * step[1] + step[2] * step[2] + step[3] * step[3])
        scale = 2.0 * math.atan2(s, step[0]) / s if s > 1e-15 else 2.0
        for k in range(3):
            w_B[k] = step[k + 1] * scale / dt_last
        if with_p:
            for k in range(3):
                v_B[k] = (p_BoEo_B[P - 1, k] - p_BoEo_B[P - 2, k]) / float(last - pose_t_ns[P - 2])
    turn = np.empty(4)
    for n in range(len(t_ns)):
        t = t_ns[n]
        q = out_quat_BE[n]
        out_stale[n] = t < first or t > last + period_ns
        if t < first:
            q[:] = quat_BE[0]
            if with_p:
                out_p_BoEo_B[n] = p_BoEo_B[0]
        elif t <= last:
            i = np.searchsorted(pose_t_ns, t, side="right") - 1
            i = max(min(i, max(P - 2, 0)), 0)
            j = min(i + 1, P - 1)
            span = float(pose_t_ns[j] - pose_t_ns[i])
            u = (t - pose_t_ns[i]) / span if span > 0 else 0.0
            _slerp(quat_BE[i], quat_BE[j], u, q)
            if with_p:
                for k in range(3):
                    out_p_BoEo_B[n, k] = p_BoEo_B[i, k] + u * (p_BoEo_B[j, k] - p_BoEo_B[i, k])
        else:
            dt_ns = min(t - last, period_ns)
            if moving:
                dt = dt_ns * 1e-9
                angle = math.sqrt((w_B[0] * dt) ** 2 + (w_B[1] * dt) ** 2 + (w_B[2] * dt) ** 2)
                k_half = math.sin(0.5 * angle) / angle if angle > 1e-12 else 0.5
                turn[0] = math.cos(0.5 * angle)
                for k in range(3):
                    turn[k + 1] = w_B[k] * dt * k_half
                _multiply(turn, quat_BE[P - 1], q)
            else:
                q[:] = quat_BE[P - 1]
            if with_p:
                for k in range(3):
                    out_p_BoEo_B[n, k] = p_BoEo_B[P - 1, k] + v_B[k] * dt_ns if moving else p_BoEo_B[P - 1, k]
        w, x, y, z = q[0], q[1], q[2], q[3]
        R = out_R_EB[n]  # R_BE transposed
        R[0, 0] = 1 - 2 * (y * y + z * z)
        R[1, 0] = 2 * (x * y - w * z)
        R[2, 0] = 2 * (x * z + w * y)
        R[0, 1] = 2 * (x * y + w * z)
        R[1, 1] = 1 - 2 * (x * x + z * z)
        R[2, 1] = 2 * (y * z - w * x)
        R[0, 2] = 2 * (x * z - w * y)
        R[1, 2] = 2 * (y * z + w * x)
        R[2, 2] = 1 - 2 * (x * x + y * y)


def warm_up() -> None:
    """Compile (or load from the cache) ``align_block`` before the first live tick."""
    t = np.array([0, 1_000_000, 3_000_000], dtype=np.int64)
    pose_t = np.array([500_000, 2_000_000], dtype=np.int64)
    quat = np.array([[1.0, 0.0, 0.0, 0.0], [0.9998, 0.02, 0.0, 0.0]])
    quat /= np.linalg.norm(quat, axis=1)[:, None]
    p = np.zeros((2, 3))
    align_block(
        t,
        pose_t,
        quat,
        p,
        2_000_000,
        np.empty((3, 4)),
        np.empty((3, 3, 3)),
        np.empty((3, 3)),
        np.empty(3, dtype=np.bool_),
    )
