"""The aligner: slerp between poses, at most one period of extrapolation, stale flags."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.aligner import Aligner, orientation_at
from hapticlab.core.types import PoseSample, WrenchSample

W = np.array([0.3, -0.5, 0.8])  # rad/s, constant angular velocity in B


def rotating(t_s: np.ndarray) -> Rotation:
    """R_BE(t) = exp(ω t) R0: a robot turning at constant angular velocity."""
    return Rotation.from_rotvec(np.outer(t_s, W)) * Rotation.from_rotvec([0.2, 0.1, -0.3])


def test_interpolation_between_poses_is_exact_for_constant_rate():
    pose_t = np.arange(0, 11) * 2_000_000  # 500 Hz
    quat = rotating(pose_t * 1e-9).as_quat(scalar_first=True)
    t = np.arange(0, 20_000_001, 142_857)  # 7 kHz
    out, stale = orientation_at(t, pose_t, quat, 2_000_000)
    ref = rotating(t * 1e-9)
    assert not stale.any()
    assert np.allclose(Rotation.from_quat(out, scalar_first=True).as_matrix(), ref.as_matrix(), atol=1e-12)


def test_extrapolation_is_limited_to_one_period_and_flagged_beyond():
    period = 2_000_000
    pose_t = np.arange(0, 5) * period
    quat = rotating(pose_t * 1e-9).as_quat(scalar_first=True)
    last = pose_t[-1]
    t = np.array([last + period // 2, last + period, last + period + 1, last + 5 * period, -1])
    out, stale = orientation_at(t, pose_t, quat, period)
    assert stale.tolist() == [False, False, True, True, True]
    R = Rotation.from_quat(out, scalar_first=True).as_matrix()
    # constant-rate motion extrapolates exactly within the allowed period ...
    assert np.allclose(R[:2], rotating(t[:2] * 1e-9).as_matrix(), atol=1e-12)
    # ... and is held at one period ahead beyond it, never further
    assert np.allclose(R[3], rotating(np.array([(last + period) * 1e-9])).as_matrix()[0], atol=1e-12)
    assert np.allclose(R[4], rotating(np.array([0.0])).as_matrix()[0], atol=1e-12)


def test_live_aligner_blocks():
    aligner = Aligner(kinematics_rate_hz=500.0)
    wrench = [WrenchSample(k * 1_000_000, np.zeros(3), np.zeros(3), k) for k in range(5)]
    before = aligner.align(wrench)
    assert before.stale.all()  # no pose yet: nothing can be aligned
    poses = [PoseSample(k * 2_000_000, rotating(np.array([k * 2e-3])).as_quat(scalar_first=True)[0]) for k in range(3)]
    aligner.add_poses(poses)
    block = aligner.align(wrench)
    assert not block.stale.any() and block.seq.tolist() == [0, 1, 2, 3, 4]
    R_BE = block.R_EB.transpose(0, 2, 1)
    assert np.allclose(R_BE, rotating(np.arange(5) * 1e-3).as_matrix(), atol=1e-12)
    assert np.allclose(Rotation.from_quat(block.quat_BE, scalar_first=True).as_matrix(), R_BE)
