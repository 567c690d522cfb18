"""The simulated kinematics' reported orientation, compiled: a rotation matrix to a quaternion, turned by
the encoders' jitter.

The compiled twin of ``plugins/kinematics/sim.py``'s numpy path (``frames.quat_wxyz_from_matrix``, then
q + ½ q ⊗ [0, δ] normalised), for a live simulated robot, whose poses are asked for one at a time
(numpy's calls cost more than the arithmetic there: docs/devices.md). Shepperd's method: the row of

    K = [[1 + tr,     R21 − R12,       R02 − R20,       R10 − R01     ],
         [R21 − R12,  1 − tr + 2 R00,  R10 + R01,       R20 + R02     ],
         [R02 − R20,  R10 + R01,       1 − tr + 2 R11,  R21 + R12     ],
         [R10 − R01,  R20 + R02,       R21 + R12,       1 − tr + 2 R22]]

with the largest diagonal (4 q_i q), normalised with w ≥ 0. The same operations in the same order as the
numpy path (tests/plugins/simworld/test_servo_and_tissue.py holds them to 1e-15).

Compile cost: well under a second the first time, then loaded from ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hapticlab.core.aligner_kernel import _multiply


@njit(cache=True)
def reported_quat(R_BE, delta, jitter, out):
    """Fill ``out`` (n, 4) with the [w, x, y, z] quaternion of each ``R_BE`` (n, 3, 3), w ≥ 0; when
    ``jitter``, turned by the small rotation ``delta`` (n, 3) rad in E: q + ½ q ⊗ [0, δ], normalised."""
    K = np.empty(4)
    turn = np.zeros(4)  # [0, δ]
    product = np.empty(4)
    for i in range(R_BE.shape[0]):
        R = R_BE[i]
        trace = R[0, 0] + R[1, 1] + R[2, 2]
        diag0 = 1.0 + trace
        diag1 = (1.0 - trace) + 2.0 * R[0, 0]
        diag2 = (1.0 - trace) + 2.0 * R[1, 1]
        diag3 = (1.0 - trace) + 2.0 * R[2, 2]
        best, row = diag0, 0
        if diag1 > best:
            best, row = diag1, 1
        if diag2 > best:
            best, row = diag2, 2
        if diag3 > best:
            best, row = diag3, 3
        if row == 0:
            K[0], K[1], K[2], K[3] = diag0, R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
        elif row == 1:
            K[0], K[1], K[2], K[3] = R[2, 1] - R[1, 2], diag1, R[0, 1] + R[1, 0], R[0, 2] + R[2, 0]
        elif row == 2:
            K[0], K[1], K[2], K[3] = R[0, 2] - R[2, 0], R[0, 1] + R[1, 0], diag2, R[1, 2] + R[2, 1]
        else:
            K[0], K[1], K[2], K[3] = R[1, 0] - R[0, 1], R[0, 2] + R[2, 0], R[1, 2] + R[2, 1], diag3
        scale = (-1.0 if K[0] < 0 else 1.0) / math.sqrt(K[0] * K[0] + K[1] * K[1] + K[2] * K[2] + K[3] * K[3])
        for k in range(4):
            K[k] *= scale
        if jitter:
            turn[1], turn[2], turn[3] = delta[i, 0], delta[i, 1], delta[i, 2]
            _multiply(K, turn, product)
            for k in range(4):
                K[k] += 0.5 * product[k]
            norm = math.sqrt(K[0] * K[0] + K[1] * K[1] + K[2] * K[2] + K[3] * K[3])
            for k in range(4):
                K[k] /= norm
        out[i, :] = K


def warm_up() -> None:
    """Compile (or load from the cache) ``reported_quat`` before the first live tick."""
    reported_quat(np.eye(3)[None], np.zeros((1, 3)), True, np.empty((1, 4)))
