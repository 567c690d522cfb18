"""The ``batch`` estimator's compiled flags (``conditioned_kernel``) against its numpy reference (an SVD per
sample): the same bits, contact wrench and flags, on seeded simulated physics with a tilted robot base, in
blocks of any size, and on fits that stay ill-conditioned (where the kernel must leave the flag to gesdd)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import KEYS, run_blocks

from hapticlab.plugins.estimators.batch import BatchEstimator
from hapticlab.plugins.estimators.batch import conditioned_kernel as ck
from hapticlab.plugins.simworld import SimWorld
from hapticlab.plugins.simworld.params import RobotParams
from hapticlab.sessions.bench.simulation import simulate


@pytest.fixture(scope="module")
def tilted():
    """6 s at 1 kHz of the random tour (seed 4) on a base tilted by ~8.6 degrees."""
    world = SimWorld(robot=RobotParams(base_tilt_BG=(0.12, -0.08, 0.05)), seed=4, inertia=False)
    block, _ = simulate(world, 6.0, 1000.0)
    return block


@pytest.mark.parametrize("size", [7, 37, 6000])
@pytest.mark.parametrize("calibration_samples", [0, 2500])
def test_kernel_gives_the_reference_bits(tilted, size, calibration_samples):
    ref = BatchEstimator(kernel="numpy", calibration_samples=calibration_samples)
    fast = BatchEstimator(kernel="numba", calibration_samples=calibration_samples)
    a, b = run_blocks(ref, tilted, size), run_blocks(fast, tilted, size)
    for key in KEYS:
        assert np.array_equal(a[key], b[key]), key
    assert ref.params() == fast.params()
    # the tour both starts unconverged and converges, so both of the kernel's outcomes were taken
    assert not a["converged_torque"][0] and a["converged_force"][-1] and a["converged_torque"][-1]


def test_flags_near_the_threshold_are_left_to_gesdd():
    """Scaled matrices with rcond spread over 1e-7..1: what the kernel proves agrees with gesdd, and it
    proves every one whose smallest eigenvalue exceeds min_rcond times the largest absolute row sum (≤ 6)."""
    rng = np.random.default_rng(7)
    n = 4000
    Q = np.linalg.qr(rng.normal(size=(n, 6, 6)))[0]
    r = np.exp(rng.uniform(np.log(1e-7), 0.0, size=(n, 1)))
    s = r ** rng.uniform(0.0, 1.0, size=(n, 6))
    s[:, 0], s[:, 1] = 1.0, r[:, 0]
    M = Q @ (s[:, :, None] * Q.transpose(0, 2, 1))
    d = np.sqrt(np.einsum("kii->ki", M))
    M = M / (d[:, :, None] * d[:, None, :])
    sv = np.linalg.svd(M, compute_uv=False)
    for min_rcond in (1e-12, 1e-4, 1e-2):
        code = np.empty(n, dtype=np.int8)
        undecided = ck.certain(M, min_rcond, code)
        up = code == ck.UP
        assert undecided == n - up.sum()
        assert np.all(sv[up, -1] / sv[up, 0] >= min_rcond)
        clearly = sv[:, -1] >= 7 * min_rcond * sv[:, 0]
        assert clearly.sum() > 100 and up[clearly].all()


def test_zero_and_nonfinite_matrices_are_undecided():
    code = np.empty(3, dtype=np.int8)
    M = np.stack([np.zeros((6, 6)), np.full((6, 6), np.nan), np.eye(6)])
    assert ck.certain(M, 1e-4, code) == 2
    assert list(code) == [ck.UNDECIDED, ck.UNDECIDED, ck.UP]


def test_kernel_option_is_checked():
    with pytest.raises(ValueError, match="kernel"):
        BatchEstimator(kernel="fortran")


CHOLESKY_FORCE = 1e-10
"""How far ``solver = "cholesky"``'s contact force may be from the reference's (N): its solve and pinv's SVD
round differently, by up to cond(M)·eps relative where it is used (cond(M) ≤ 6/min_rcond). Measured: 2.6e-12 N
on this tour (2.0e-12 N over 120 s of it), at most 1.5e-11 N on the six real recordings (ATI Axia80, KUKA LWR4)."""
CHOLESKY_TORQUE = 1e-11
"""The same for the contact torque (N·m). Measured: 1.1e-13 here, at most 1.0e-12 on the real recordings."""


@pytest.mark.parametrize("size", [37, 6000])
def test_cholesky_solver_is_the_reference_within_rounding(tilted, size):
    ref = BatchEstimator(kernel="numpy")
    fast = BatchEstimator(solver="cholesky")
    a, b = run_blocks(ref, tilted, size), run_blocks(fast, tilted, size)
    for key in ("contact", "converged_force", "converged_torque"):
        assert np.array_equal(a[key], b[key]), key
    assert np.max(np.abs(a["contact_force_S"] - b["contact_force_S"])) <= CHOLESKY_FORCE
    assert np.max(np.abs(a["contact_torque_S"] - b["contact_torque_S"])) <= CHOLESKY_TORQUE
    # not the reference's bits: the solve did run (the first samples, unproved, are pinv's own)
    assert not np.array_equal(a["contact_force_S"], b["contact_force_S"])
    assert np.array_equal(a["contact_force_S"][:3], b["contact_force_S"][:3])
    for key, value in ref.params().items():
        assert np.allclose(value, fast.params()[key], rtol=1e-12, atol=1e-13), key


def test_solver_option_is_checked():
    with pytest.raises(ValueError, match="solver"):
        BatchEstimator(solver="qr")
