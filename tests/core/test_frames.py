"""Frame helpers against scipy and against their definitions."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from hapticlab.core.frames import (
    cross,
    matrix_from_quat_wxyz,
    matrix_from_rotvec,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_slerp,
    quat_wxyz_from_matrix,
    rotvec_from_matrix,
    rotvec_from_quat,
    skew,
    skew_stack,
)

ROT = Rotation.random(200, random_state=3)
Q = ROT.as_quat(scalar_first=True)


def test_matrix_from_quat_matches_scipy():
    assert np.allclose(matrix_from_quat_wxyz(Q), ROT.as_matrix(), atol=1e-14)
    assert np.allclose(matrix_from_quat_wxyz(Q[0]), ROT[0].as_matrix(), atol=1e-14)
    back = quat_wxyz_from_matrix(ROT.as_matrix())
    assert np.allclose(np.abs(np.einsum("ij,ij->i", back, Q)), 1.0)  # q and −q are one rotation


def test_monogram_composition():
    R_BE, R_ES = ROT[:100].as_matrix(), ROT[100:].as_matrix()
    q = quat_multiply(Q[:100], Q[100:])  # q_BS = q_BE ⊗ q_ES
    assert np.allclose(matrix_from_quat_wxyz(q), R_BE @ R_ES, atol=1e-13)
    assert np.allclose(matrix_from_quat_wxyz(quat_conjugate(Q)), ROT.as_matrix().transpose(0, 2, 1), atol=1e-14)


def test_slerp_matches_scipy():
    u = np.linspace(0, 1, 100)
    ours = quat_slerp(Q[:100], Q[100:], u)
    for k in (0, 17, 50, 99):
        pair = Rotation.concatenate([ROT[k], ROT[100 + k]])
        ref = Slerp([0.0, 1.0], pair)([u[k]]).as_matrix()[0]
        assert np.allclose(matrix_from_quat_wxyz(ours[k]), ref, atol=1e-12)
    same = quat_slerp(Q[:3], Q[:3], np.array([0.0, 0.4, 1.0]))  # identical ends
    assert np.allclose(np.abs(np.einsum("ij,ij->i", same, Q[:3])), 1.0)


def test_rotvec_round_trip_and_scipy():
    v = ROT.as_rotvec()
    assert np.allclose(matrix_from_quat_wxyz(quat_from_rotvec(v)), ROT.as_matrix(), atol=1e-13)
    for k in range(10):
        assert np.allclose(rotvec_from_quat(Q[k]), v[k], atol=1e-12)
    assert np.allclose(quat_from_rotvec(np.zeros((1, 3))), [[1, 0, 0, 0]])


def test_one_matrix_and_one_rotvec_take_the_float_path_and_match_scipy():
    """The single-rotation paths (Shepperd, Rodrigues in floats) against scipy, with the corners: the
    identity, angles at and below the series' switch, and angles at and next to π (where the axis's
    sign is free: the matrices are compared)."""
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(8, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    corners = [a * t for a, t in zip(axes, (0.0, 1e-12, 1e-5, 1e-4, 0.7, np.pi - 1e-3, np.pi - 1e-8, np.pi))]
    for v in [*ROT.as_rotvec(), *corners]:
        R = Rotation.from_rotvec(v).as_matrix()
        assert np.abs(matrix_from_rotvec(v) - R).max() < 1e-15 * 8
        r = rotvec_from_matrix(R)
        assert np.linalg.norm(r) <= np.pi + 1e-15
        assert np.abs(Rotation.from_rotvec(r).as_matrix() - R).max() < 1e-15 * 8
        if np.linalg.norm(v) < np.pi - 1e-6:  # a unique rotation vector: the same one
            assert np.allclose(r, Rotation.from_matrix(R).as_rotvec(), rtol=0, atol=1e-12)
    singles = np.array([quat_wxyz_from_matrix(R) for R in ROT.as_matrix()])  # floats, one at a time
    assert np.abs(singles - quat_wxyz_from_matrix(ROT.as_matrix())).max() < 1e-15 and (singles[:, 0] >= 0).all()
    stack = ROT.as_matrix()[:5]  # stacks still go through scipy
    assert np.allclose(rotvec_from_matrix(stack), ROT[:5].as_rotvec(), atol=1e-14)
    assert np.allclose(matrix_from_rotvec(ROT[:5].as_rotvec()), stack, atol=1e-14)


def test_cross_and_skew():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    assert np.allclose(cross(a, b), np.cross(a, b))
    assert np.allclose(cross(a[0], b), np.cross(a[0], b))
    assert np.allclose(skew(a[0]) @ b[0], np.cross(a[0], b[0]))
    assert np.allclose(skew_stack(a) @ b[:, :, None], np.cross(a, b)[:, :, None])
