"""Frame conventions and rotation helpers.

Frames: B robot base, E robot end (flange), S sensor, G gravity, D haptic
device base, H device handle. Drake monogram notation: ``R_EB`` is the
orientation of frame B in frame E, so ``v_E = R_EB @ v_B``; compose by
cancelling letters (``R_SG = R_SE @ R_EB @ R_BG``); invert by swapping them
(``R_BE = R_EB.T``). The paper's :math:`{}^{E}_{B}R` is ``R_EB``.

Quaternions are [w, x, y, z] (scalar first) at every interface, as in the CSV
contract and the MCAP topics. Rotations go through ``scipy.spatial.transform``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY_M_S2 = 9.80665
"""Standard gravity, m/s²."""


def skew(v: np.ndarray) -> np.ndarray:
    """The (3, 3) matrix with ``skew(v) @ u == np.cross(v, u)``."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b over the last axis, with broadcasting ((3,), (N, 3) or mixed).

    Component formulas: np.cross's axis handling costs more than the arithmetic
    per call, which matters in the per-sample loop.
    """
    a = np.asarray(a)
    b = np.asarray(b)
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), np.result_type(a, b))  # (no np.stack copy)
    np.subtract(ay * bz, az * by, out=out[..., 0])
    np.subtract(az * bx, ax * bz, out=out[..., 1])
    np.subtract(ax * by, ay * bx, out=out[..., 2])
    return out


def skew_stack(v: np.ndarray) -> np.ndarray:
    """(m, 3, 3) stack of skew(v_k) for (m, 3) vectors."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2] = -v[:, 2], v[:, 1]
    out[:, 1, 0], out[:, 1, 2] = v[:, 2], -v[:, 0]
    out[:, 2, 0], out[:, 2, 1] = -v[:, 1], v[:, 0]
    return out


def matrix_from_quat_wxyz(quat_wxyz: np.ndarray) -> np.ndarray:
    """(3, 3) or (N, 3, 3) rotation matrices from unit [w, x, y, z] quaternions.

    The textbook formula in plain numpy: the live loop converts a few
    quaternions per millisecond, where building a scipy Rotation per call
    would cost more than the arithmetic. Tested against scipy.
    """
    q = np.asarray(quat_wxyz, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a ⊗ b of [w, x, y, z] quaternions (broadcasting), so R(a⊗b) = R(a) R(b)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of unit [w, x, y, z] quaternions: the orientation R_AB of a given R_BA."""
    conjugate: np.ndarray = np.asarray(q, dtype=float) * np.array([1.0, -1.0, -1.0, -1.0])
    return conjugate


def quat_slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between (n, 4) quaternions at fractions u (n,) in [0, 1]."""
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float)
    dot = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)  # the shorter way round
    theta = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    safe = np.where(small, 1.0, sin_theta)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(small, u, np.sin(u * theta) / safe)
    q = w0[:, None] * q0 + w1[:, None] * q1
    unit: np.ndarray = q / np.linalg.norm(q, axis=1, keepdims=True)
    return unit


def quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(n, 4) [w, x, y, z] quaternions of (n, 3) rotation vectors (axis · angle, rad)."""
    rotvec = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(rotvec, axis=-1)
    half = 0.5 * angle
    # sin(θ/2)/θ, with its limit 1/2 at θ = 0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half)[..., None], rotvec * k[..., None]], axis=-1)


def rotvec_from_quat(q: np.ndarray | Sequence[float]) -> np.ndarray:
    """Rotation vector (axis · angle, rad) of one [w, x, y, z] unit quaternion, angle in [0, π] (plain floats)."""
    w, x, y, z = (float(v) for v in q)
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 * math.atan2(s, w) / s if s > 1e-15 else 2.0  # angle / sin(angle / 2), its limit 2 at 0
    return np.array([x * k, y * k, z * k])


_VEE = np.array([7, 2, 3])
"""Flat indices of (2, 1), (0, 2), (1, 0) in a 3×3 matrix: the vector of a skew-symmetric one."""


def quat_wxyz_from_matrix(R: np.ndarray) -> np.ndarray:
    """(4,) or (N, 4) unit quaternions [w, x, y, z] of (3, 3) or (N, 3, 3) rotation matrices, w >= 0.

    Shepperd's method (as in scipy's ``Rotation.from_matrix``) in plain numpy: the
    live loop converts one pose per read, where building a scipy Rotation costs
    more than the arithmetic. Every row of the symmetric matrix ::

        K = [[1 + tr,     R21 − R12,       R02 − R20,       R10 − R01     ],
             [R21 − R12,  1 − tr + 2 R00,  R10 + R01,       R20 + R02     ],
             [R02 − R20,  R10 + R01,       1 − tr + 2 R11,  R21 + R12     ],
             [R10 − R01,  R20 + R02,       R21 + R12,       1 − tr + 2 R22]]

    is ``4 q_i q`` (i its index in [w, x, y, z]), so its diagonal is ``4 q_i²``;
    the row with the largest diagonal, normalised, is the best-conditioned
    estimate of q. Assumes proper rotation matrices.
    """
    R = np.asarray(R, dtype=float)
    if R.ndim == 2:  # one matrix: the same method in plain floats (no array overhead)
        return np.array(_quat_floats(R))
    n = len(R)
    R_flat = R.reshape(n, 9)
    trace = R_flat[:, 0] + R_flat[:, 4] + R_flat[:, 8]
    K = np.empty((n, 4, 4))
    K_flat = K.reshape(n, 16)  # a view: K is contiguous
    K[:, 1:, 1:] = R + R.transpose(0, 2, 1)
    K_flat[:, 5::5] = (1.0 - trace)[:, None] + 2.0 * R_flat[:, ::4]  # 1 − tr + 2 R_ii
    K_flat[:, 0] = 1.0 + trace
    K[:, 0, 1:] = K[:, 1:, 0] = (R - R.transpose(0, 2, 1)).reshape(n, 9)[:, _VEE]
    quat: np.ndarray = K[np.arange(n), np.argmax(K_flat[:, ::5], axis=1)]
    # normalise, and pick the sign with w >= 0 (the same rotation, easier to read)
    quat *= np.where(quat[:, :1] < 0, -1.0, 1.0) / np.linalg.norm(quat, axis=1, keepdims=True)
    return quat


def _quat_floats(R: np.ndarray) -> tuple[float, float, float, float]:
    """:func:`quat_wxyz_from_matrix` of one (3, 3) matrix in plain floats: (w, x, y, z), w >= 0."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    trace = r00 + r11 + r22
    diag = (1.0 + trace, 1.0 - trace + 2.0 * r00, 1.0 - trace + 2.0 * r11, 1.0 - trace + 2.0 * r22)
    i = diag.index(max(diag))  # the best-conditioned row of K (4 q_i q)
    if i == 0:
        w, x, y, z = diag[0], r21 - r12, r02 - r20, r10 - r01
    elif i == 1:
        w, x, y, z = r21 - r12, diag[1], r10 + r01, r20 + r02
    elif i == 2:
        w, x, y, z = r02 - r20, r10 + r01, diag[2], r21 + r12
    else:
        w, x, y, z = r10 - r01, r20 + r02, r21 + r12, diag[3]
    norm = math.sqrt(w * w + x * x + y * y + z * z) * (-1.0 if w < 0 else 1.0)
    return w / norm, x / norm, y / norm, z / norm


def rotvec_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation vector (axis · angle, rad, angle in [0, π]) of a (3, 3) rotation matrix, or (N, 3) of (N, 3, 3).

    One matrix (the live loop's case: teleoperation turns its target every tick) goes through Shepperd's
    method in plain floats (see :func:`quat_wxyz_from_matrix`), where scipy's ``Rotation`` costs more to
    build than the arithmetic; a stack goes through scipy. The two agree to rounding (tests).
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        rotvecs: np.ndarray = Rotation.from_matrix(R).as_rotvec()
        return rotvecs
    return rotvec_from_quat(_quat_floats(R))


def matrix_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a (3,) rotation vector (axis · angle, rad), or (N, 3, 3) of (N, 3).

    One vector: Rodrigues' formula R = I + A [v]× + B [v]×², A = sin θ / θ, B = (1 − cos θ) / θ², in
    plain floats (their series below 1e-4 rad); a stack goes through scipy.
    """
    rotvec = np.asarray(rotvec, dtype=float)
    if rotvec.shape != (3,):
        matrices: np.ndarray = Rotation.from_rotvec(rotvec).as_matrix()
        return matrices
    x, y, z = rotvec.tolist()
    theta2 = x * x + y * y + z * z
    if theta2 < 1e-8:  # θ < 1e-4: the series' next terms are below 1e-18
        a, b = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
    else:
        theta = math.sqrt(theta2)
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2
    return np.array(
        [
            [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
        ]
    )
