"""The ``sim`` kinematics: the simulated robot's flange pose from the session's world.

Samples come at ``rate_hz`` from the time the source is opened, like the ``sim``
sensor: sample i at ``t0_ns + round(i·1e9/rate_hz)`` ns, world time
``(t_ns − t0_ns)/1e9`` s, carrying ``quat_BE`` [w, x, y, z] and ``p_BoEo_B`` (m).
"""

from __future__ import annotations

import numpy as np
from hapticlab.core import hookimpl
from hapticlab.core.plugins import ConfigError
from hapticlab.core.types import PoseSample
from hapticlab.plugins.simworld.physics import SampleClock, SimWorld

_VEE = np.array([7, 2, 3])
"""Flat indices of (2, 1), (0, 2), (1, 0) in a 3×3 matrix: the vector of a skew-symmetric one."""


def quat_wxyz_from_matrices(R: np.ndarray) -> np.ndarray:
    """(N, 4) unit quaternions [w, x, y, z] of (N, 3, 3) rotation matrices, w >= 0.

    Shepperd's method (as in scipy's ``Rotation.from_matrix``) in plain numpy: the
    live loop converts one pose per read, where building a scipy Rotation costs
    ~35 µs. Every row of the symmetric matrix ::

        K = [[1 + tr,     R21 − R12,       R02 − R20,       R10 − R01     ],
             [R21 − R12,  1 − tr + 2 R00,  R10 + R01,       R20 + R02     ],
             [R02 − R20,  R10 + R01,       1 − tr + 2 R11,  R21 + R12     ],
             [R10 − R01,  R20 + R02,       R21 + R12,       1 − tr + 2 R22]]

    is ``4 q_i q`` (i its index in [w, x, y, z]), so its diagonal is ``4 q_i²``;
    the row with the largest diagonal, normalised, is the best-conditioned
    estimate of q. Assumes proper rotation matrices.
    """
    n = len(R)
    R_flat = R.reshape(n, 9)
    trace = R_flat[:, 0] + R_flat[:, 4] + R_flat[:, 8]
    K = np.empty((n, 4, 4))
    K_flat = K.reshape(n, 16)  # a view: K is contiguous
    K[:, 1:, 1:] = R + R.transpose(0, 2, 1)
    K_flat[:, 5::5] = (1.0 - trace)[:, None] + 2.0 * R_flat[:, ::4]  # 1 − tr + 2 R_ii
    K_flat[:, 0] = 1.0 + trace
    K[:, 0, 1:] = K[:, 1:, 0] = (R - R.transpose(0, 2, 1)).reshape(n, 9)[:, _VEE]
    quat = K[np.arange(n), np.argmax(K_flat[:, ::5], axis=1)]
    # normalise, and pick the sign with w >= 0 (the same rotation, easier to read)
    quat *= np.where(quat[:, :1] < 0, -1.0, 1.0) / np.linalg.norm(quat, axis=1, keepdims=True)
    return quat


class SimKinematics:
    """Forward kinematics of the simulated robot (KinematicsSource).

    Parameters
    ----------
    rate_hz : sample rate, Hz (UR RTDE runs at 125 or 500 Hz).
    world : the session's SimWorld (provided by the host, shared with the ``sim`` sensor).
    """

    def __init__(self, rate_hz: float = 500.0, world: SimWorld | None = None):
        if world is None:
            raise ConfigError("kinematics sim: needs the session's simulated world; "
                              "add a [world] table to the session (or pass world=SimWorld(...))")
        if not rate_hz > 0:
            raise ConfigError(f"kinematics.rate_hz: must be > 0, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.world = world
        self._clock = SampleClock(self.rate_hz)

    def open(self, t0_ns: int) -> None:
        """Start streaming: sample 0 is at ``t0_ns`` (world time 0)."""
        self._clock.start(t0_ns)

    def read(self, until_ns: int) -> list[PoseSample]:
        """Every pose not yet returned with time <= ``until_ns``, in time order."""
        seq, t_ns = self._clock.take(until_ns)
        if len(seq) == 0:
            return []
        R_BE, p_BoEo_B = self.world.pose((t_ns - self._clock.t0_ns) / 1e9)
        quat_BE = quat_wxyz_from_matrices(R_BE)
        quat_BE.setflags(write=False)  # rows are handed out as views
        p_BoEo_B.setflags(write=False)
        return [PoseSample(t_ns=t, quat_BE=quat, p_BoEo_B=p)
                for t, quat, p in zip(t_ns.tolist(), quat_BE, p_BoEo_B)]

    def close(self) -> None:
        """Stop streaming (nothing to release)."""
        self._clock.t0_ns = None


@hookimpl
def register_kinematics(register):
    """Register the simulated robot's kinematics as ``sim``."""
    register("sim", SimKinematics)
