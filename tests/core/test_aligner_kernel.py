"""The compiled aligner (``core.aligner_kernel``) against the numpy reference (``orientation_at``, ``position_at``)."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.aligner import Aligner
from hapticlab.core.frames import quat_multiply
from hapticlab.core.types import PoseSample, WrenchSample

PERIOD_NS = 2_000_000


def pose_stream(rng: np.random.Generator, n: int, positions: bool) -> list[PoseSample]:
    """A tool turning at up to 3 rad/s about a wandering axis, sampled at 500 Hz with 0.3 ms of timing jitter;
    every quaternion's sign flipped at random (q and −q are one orientation: the slerp must go the short way)."""
    t = np.cumsum(np.full(n, PERIOD_NS) + rng.integers(-300_000, 300_000, n)).astype(np.int64)
    q = [np.array([1.0, 0.0, 0.0, 0.0])]
    for _ in range(n - 1):
        w = rng.normal(size=3) * 3.0 * PERIOD_NS * 1e-9 / np.sqrt(3)
        half = 0.5 * np.linalg.norm(w)
        step = np.concatenate([[np.cos(half)], np.sin(half) * w / (2 * half)])
        q.append(quat_multiply(step, q[-1]))
    signs = np.where(rng.random(n) < 0.5, -1.0, 1.0)
    p = np.cumsum(rng.normal(size=(n, 3)) * 1e-4, axis=0)
    return [PoseSample(t_ns=int(t[i]), quat_BE=q[i] * signs[i], p_BoEo_B=p[i] if positions else None) for i in range(n)]


def wrenches_between(rng: np.random.Generator, t0: int, t1: int, count: int) -> list[WrenchSample]:
    t = np.sort(rng.integers(t0, t1, count))
    return [
        WrenchSample(t_ns=int(ti), force_S=rng.normal(size=3), torque_S=rng.normal(size=3), seq=i, status=0)
        for i, ti in enumerate(t)
    ]


@pytest.mark.parametrize("positions", [True, False])
def test_compiled_and_numpy_aligners_agree_on_every_case(positions, numpy_reference):
    """Blocks of 1, 7 and 40 samples that fall between poses, on a pose, before the first pose, within one
    period after the newest (extrapolated) and beyond it (stale), as a live loop sees them."""
    rng = np.random.default_rng(12)
    poses = pose_stream(rng, 400, positions)
    numba_aligner, numpy_aligner = Aligner(500.0, kernel="numba"), Aligner(500.0, kernel=numpy_reference)
    compared = 0
    block_sizes = [1, 7, 40]
    for k in range(0, len(poses), 3):
        new = poses[k : k + 3]
        for aligner in (numba_aligner, numpy_aligner):
            aligner.add_poses(new)
        t_newest = new[-1].t_ns
        size = block_sizes[(k // 3) % 3]
        start = poses[max(k - 10, 0)].t_ns - (3_000_000 if k == 0 else 0)  # before the first pose on the first
        block = wrenches_between(rng, start, t_newest + 3 * PERIOD_NS, size)
        block[0] = WrenchSample(
            t_ns=poses[max(k - 1, 0)].t_ns, force_S=block[0].force_S, torque_S=block[0].torque_S, seq=0, status=0
        )  # exactly on a pose
        block.sort(key=lambda w: w.t_ns)
        a, b = numba_aligner.align(block), numpy_aligner.align(block)
        np.testing.assert_array_equal(a.stale, b.stale)
        np.testing.assert_allclose(a.quat_BE, b.quat_BE, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.R_EB, b.R_EB, rtol=0, atol=1e-12)
        if positions:
            np.testing.assert_allclose(a.p_BoEo_B, b.p_BoEo_B, rtol=0, atol=1e-15)
        else:
            assert a.p_BoEo_B is None and b.p_BoEo_B is None
        compared += len(block)
    assert compared > 2000


def test_one_pose_and_a_repeated_stamp_hold_the_orientation():
    """With one pose (or two with the same stamp) there is no velocity: every sample gets that pose."""
    q = np.array([0.5, 0.5, 0.5, 0.5])
    for poses in (
        [PoseSample(t_ns=1_000_000, quat_BE=q, p_BoEo_B=np.ones(3))],
        [
            PoseSample(t_ns=1_000_000, quat_BE=-q, p_BoEo_B=np.ones(3)),
            PoseSample(t_ns=1_000_000, quat_BE=q, p_BoEo_B=np.ones(3)),
        ],
    ):
        out = []
        for kernel in ("numba", "numpy"):
            aligner = Aligner(500.0, kernel=kernel)
            aligner.add_poses(poses)
            out.append(
                aligner.align(
                    [
                        WrenchSample(t_ns=t, force_S=np.zeros(3), torque_S=np.zeros(3), seq=0, status=0)
                        for t in (0, 1_000_000, 2_500_000, 9_000_000)
                    ]
                )
            )
        for a in out:
            np.testing.assert_allclose(np.abs(a.quat_BE @ q), 1.0, atol=1e-15)
            np.testing.assert_array_equal(a.stale, [True, False, False, True])
        np.testing.assert_allclose(out[0].R_EB, out[1].R_EB, atol=1e-15)


def test_an_unknown_kernel_is_refused():
    with pytest.raises(ValueError, match="kernel"):
        Aligner(500.0, kernel="cuda")


def test_the_aligner_keeps_exactly_the_newest_poses_as_they_stream_in():
    """The pose buffer (appended in place, moved back when full) holds the newest ``keep`` poses in order
    after every batch: batches of 1–5 poses, and now and then one longer than ``keep`` itself."""
    rng = np.random.default_rng(5)
    poses = pose_stream(rng, 3000, positions=True)
    aligner = Aligner(500.0, keep=16)
    given, k = [], 0
    while k < len(poses):
        size = 40 if rng.random() < 0.02 else int(rng.integers(1, 6))
        batch = poses[k : k + size]
        aligner.add_poses(batch)
        given += batch
        k += size
        newest = given[-16:]
        np.testing.assert_array_equal(aligner._t, [p.t_ns for p in newest])
        np.testing.assert_array_equal(aligner._q, [p.quat_BE for p in newest])
        np.testing.assert_array_equal(aligner._p, [p.p_BoEo_B for p in newest])
    aligner.add_poses([PoseSample(t_ns=given[-1].t_ns + PERIOD_NS, quat_BE=np.array([1.0, 0, 0, 0]))])
    assert aligner._p is None and len(aligner._t) == 16  # a pose without a position: positions are unknown
