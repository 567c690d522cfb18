"""Pairs each wrench sample with the robot orientation at the sample's own time.

Sensor and kinematics streams run at different rates (NetFT up to 7000 Hz, UR
RTDE 125/500 Hz). Between two poses the orientation is interpolated by slerp.
After the newest pose it is extrapolated at the last measured angular
velocity for at most one kinematics period; a sample further out (or before
the first pose) gets the nearest allowed orientation and is flagged
``stale``, so the run loop can keep it away from the estimators and zero the
haptic force.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import aligner_kernel as align_kernel
from hapticlab.core.frames import (
    matrix_from_quat_wxyz,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_slerp,
    rotvec_from_quat,
)
from hapticlab.core.types import AlignedSamples, PoseSample, WrenchBlock, WrenchSample

_NO_POSITIONS = np.zeros((0, 3))
"""What the compiled aligner is given for poses without positions (and writes none into)."""


def orientation_at(
    t_ns: np.ndarray, pose_t_ns: np.ndarray, quat_BE: np.ndarray, period_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """Orientation of E in B at arbitrary times from a pose stream.

    Args:
        t_ns: (n,) query times, ns.
        pose_t_ns: (p,) increasing pose times, ns (p >= 1).
        quat_BE: (p, 4) [w, x, y, z] orientations of E in B at those times.
        period_ns: the kinematics period; the longest extrapolation allowed.

    Returns:
        (quat_BE (n, 4) at the query times, stale (n,) bool).
    """
    t_ns = np.asarray(t_ns, dtype=np.int64)
    pose_t_ns = np.asarray(pose_t_ns, dtype=np.int64)
    quat_BE = np.asarray(quat_BE, dtype=float)
    first, last = pose_t_ns[0], pose_t_ns[-1]
    out = np.empty((len(t_ns), 4))
    stale = (t_ns < first) | (t_ns > last + period_ns)

    inside = (t_ns >= first) & (t_ns <= last)
    if inside.any():
        t = t_ns[inside]
        # pose interval [i, i+1] holding each time (i = p-1 only when t == last)
        i = np.clip(np.searchsorted(pose_t_ns, t, side="right") - 1, 0, max(len(pose_t_ns) - 2, 0))
        j = np.minimum(i + 1, len(pose_t_ns) - 1)
        span = (pose_t_ns[j] - pose_t_ns[i]).astype(float)
        u = np.divide((t - pose_t_ns[i]).astype(float), span, out=np.zeros(len(t)), where=span > 0)
        out[inside] = quat_slerp(quat_BE[i], quat_BE[j], u)

    before = t_ns < first
    out[before] = quat_BE[0]

    after = t_ns > last
    if after.any():
        dt_s = np.minimum(t_ns[after] - last, period_ns) * 1e-9
        if len(pose_t_ns) >= 2 and last > pose_t_ns[-2]:
            # constant angular velocity in B from the last two poses: q(t) = exp(ω_B dt) ⊗ q(last)
            step = quat_multiply(quat_BE[-1], quat_conjugate(quat_BE[-2]))
            w_B = rotvec_from_quat(step) / ((last - pose_t_ns[-2]) * 1e-9)
            out[after] = quat_multiply(quat_from_rotvec(dt_s[:, None] * w_B), quat_BE[-1])
        else:
            out[after] = quat_BE[-1]
    return out, stale


def position_at(t_ns: np.ndarray, pose_t_ns: np.ndarray, p_BoEo_B: np.ndarray, period_ns: int) -> np.ndarray:
    """Position of E's origin in B at arbitrary times: linear between poses, constant velocity
    for at most one kinematics period after the newest (as ``orientation_at``), held outside.

    Args:
        t_ns: (n,) query times, ns. pose_t_ns: (p,) increasing pose times, ns.
        p_BoEo_B: (p, 3) positions at those times, m. period_ns: the longest extrapolation.

    Returns:
        (n, 3) positions, m.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    pose_t = np.asarray(pose_t_ns, dtype=np.int64)
    p = np.asarray(p_BoEo_B, dtype=float)
    last = pose_t[-1]
    # np.interp holds the end values; extend by one period at the last velocity
    if len(pose_t) >= 2 and last > pose_t[-2]:
        v = (p[-1] - p[-2]) / float(last - pose_t[-2])
        pose_t = np.append(pose_t, last + period_ns)
        p = np.vstack([p, p[-1] + v * period_ns])
    x = (t - pose_t[0]).astype(float)
    xp = (pose_t - pose_t[0]).astype(float)
    return np.stack([np.interp(x, xp, p[:, k]) for k in range(3)], axis=1)


class Aligner:
    """Live aligner: buffers poses, aligns wrench blocks as they arrive.

    Args:
        kinematics_rate_hz: the pose stream's nominal rate (sets the longest
            extrapolation, one period).
        latency_s: how much older than now the newest pose can be in ordinary
            operation (a networked arm, ``HasLatency``), s: added to the longest
            extrapolation.
        keep: how many recent poses to keep for interpolation.
        kernel: "numba" (``core.aligner_kernel``, compiled, the default) or
            "numpy" (``orientation_at`` and ``position_at``: the reference).
    """

    def __init__(self, kinematics_rate_hz: float, keep: int = 64, kernel: str = "numba", latency_s: float = 0.0):
        if kernel not in ("numba", "numpy"):
            raise ValueError(f"kernel: must be 'numba' or 'numpy', got {kernel!r}")
        self.period_ns = round(1e9 / kinematics_rate_hz + latency_s * 1e9)
        """The longest extrapolation past the newest pose, ns (one period, plus the source's latency)."""
        self.keep = keep
        self.kernel = kernel
        if kernel == "numba":
            align_kernel.warm_up()
        # the buffers: rows [start, end) hold the newest `keep` poses (at most); appended in place, moved
        # back to row 0 when full (a copy of `keep` rows every 3·keep poses, not a concatenation per tick)
        capacity = 4 * keep
        self._tb, self._qb, self._pb = (
            np.zeros(capacity, dtype=np.int64),
            np.zeros((capacity, 4)),
            np.zeros((capacity, 3)),
        )
        self._end = 0
        self._with_p = True  # False once a pose without a position came
        self._window(0)

    def _window(self, start: int) -> None:
        end = self._end
        self._t, self._q = self._tb[start:end], self._qb[start:end]
        self._p: np.ndarray | None = self._pb[start:end] if self._with_p else None

    def add_poses(self, poses: list[PoseSample]) -> None:
        """Append poses (in time order) to the buffer."""
        if not poses:
            return
        poses = poses[-self.keep :]
        m, end = len(poses), self._end
        if end + m > len(self._tb):  # full: the newest rows back to the start
            kept = min(end, self.keep - m)
            for buffer in (self._tb, self._qb, self._pb):
                buffer[:kept] = buffer[end - kept : end]
            end = kept
        tb, qb, pb = self._tb, self._qb, self._pb
        for i, pose in enumerate(poses, start=end):
            tb[i] = pose.t_ns
            qb[i] = pose.quat_BE
            if pose.p_BoEo_B is None:
                self._with_p = False
            elif self._with_p:
                pb[i] = pose.p_BoEo_B
        self._end = end = end + m
        self._window(max(end - self.keep, 0))

    @property
    def latest_pose_ns(self) -> int | None:
        """Time of the newest pose, or None before the first."""
        return int(self._t[-1]) if len(self._t) else None

    def align(self, wrenches: WrenchBlock | list[WrenchSample]) -> AlignedSamples:
        """Pair each wrench with its orientation; ``stale`` marks the ones that could not be. The block's
        arrays are the aligned samples' own (not copied)."""
        if not isinstance(wrenches, WrenchBlock):
            wrenches = WrenchBlock.from_samples(wrenches)
        n = len(wrenches)
        t, force_S, torque_S, seq, status = (
            wrenches.t_ns,
            wrenches.force_S,
            wrenches.torque_S,
            wrenches.seq,
            wrenches.status,
        )
        if len(self._t) == 0:
            quat_BE = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
            stale = np.ones(n, dtype=bool)
            R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
            p_BoEo_B = None
        elif self.kernel == "numba":
            quat_BE, R_EB, stale = np.empty((n, 4)), np.empty((n, 3, 3)), np.empty(n, dtype=bool)
            with_p = self._p is not None
            p_BoEo_B = np.empty((n, 3)) if with_p else None
            align_kernel.align_block(
                t,
                self._t,
                self._q,
                self._p if self._p is not None else _NO_POSITIONS,
                self.period_ns,
                quat_BE,
                R_EB,
                p_BoEo_B if p_BoEo_B is not None else _NO_POSITIONS,
                stale,
            )
        else:
            quat_BE, stale = orientation_at(t, self._t, self._q, self.period_ns)
            R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
            p_BoEo_B = None
            if self._p is not None and len(self._p):
                p_BoEo_B = position_at(t, self._t, self._p, self.period_ns)
        return AlignedSamples(t, force_S, torque_S, R_EB, seq, status, stale, quat_BE, p_BoEo_B)
