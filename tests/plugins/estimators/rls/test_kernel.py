"""The ``rls`` estimator's compiled kernel (``information_form_kernel``) against its numpy reference
(``information_form``), on the simulated tour of ``bench paper`` (``kernel_tour``, tests/helpers.py).

Not bit-for-bit. The kernel calls the same LAPACK ``dposv`` on the same Λ, but a BLAS product (Aᵀy for a
non-contiguous R_EB) may round differently by an ulp, so x differs by up to ~cond(Λ)·1e-16·‖x‖, and on this
tour cond(Λ) of the force stage reaches ~1e12 (one direction of B is barely excited for a while): x then
differs by ~1e-4 after a single update, and the convergence test ‖Δx‖ < 1e-3 decides differently where a
step lies that close to 1e-3 (4 samples of 3000). Whole runs then follow different, equally valid samples:
the numpy path in blocks of 1 and of 7 differs from itself the same way. So the kernel is held to the
reference in lockstep, one sample at a time from the reference's state, with the forward error bound of the
two solves, 1e-14·cond(Λ)·‖x‖ (a flag may differ only where the reference's step is within that bound of ε),
and the kernel must give the same bits whatever the block size (it runs sample by sample).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import KEYS, run_blocks

from hapticlab.plugins.estimators.rls import RLSEstimator

INFO = "information"
"""These tests hold the information form's kernel (``information_form_kernel``) to its reference; the default
printed update's kernel (``covariance_form_kernel``) is held to Algorithm 1 at the end."""


def _sync_rls(dst: RLSEstimator, src: RLSEstimator) -> None:
    """dst takes src's state, in place (the kernel's arrays stay the ones it was given)."""
    for a, b in ((dst.force, src.force), (dst.torque, src.torque)):
        np.copyto(a.x, b.x)
        np.copyto(a.Lambda, b.Lambda)
        np.copyto(a.eta, b.eta)
        a.updates, a.failed = b.updates, b.failed
    dst.converged_force, dst.converged_torque = src.converged_force, src.converged_torque


def test_rls_kernel_matches_numpy_in_lockstep(sim, numpy_reference):
    ref = RLSEstimator(kernel="numpy", covariance_update=INFO)
    fast = RLSEstimator(kernel="numba", covariance_update=INFO)
    decided_by_rounding = 0
    for i in range(len(sim)):
        part = sim.subset(slice(i, i + 1))
        _sync_rls(fast, ref)
        before = ref.force.x.copy(), ref.torque.x.copy()
        a, b = ref.update_block(part), fast.update_block(part)
        # the forward error of a Cholesky solve, ~3n·u·cond(Λ)·‖x‖ for each path (n = 6, u = 1.1e-16), twice;
        # the torque stage's A_k = −[f − b_f]ₓ also carries the force stage's difference in b_f
        cond_f, cond_t = np.linalg.cond(ref.force.Lambda), np.linalg.cond(ref.torque.Lambda)
        delta_A = np.linalg.norm(ref.force.x[3:] - fast.force.x[3:]) / np.linalg.norm(part.force_S[0] - ref.force.x[3:])
        bound = [
            1e-14 * cond_f * max(1.0, np.linalg.norm(ref.force.x)) + 1e-12,
            (1e-14 + 3 * delta_A) * cond_t * max(1.0, np.linalg.norm(ref.torque.x)) + 1e-12,
        ]
        steps = [np.linalg.norm(s.x - x0) for s, x0 in zip((ref.force, ref.torque), before)]
        flags_equal = all(np.array_equal(getattr(a, key), getattr(b, key)) for key in KEYS[2:])
        if not flags_equal:
            assert min(abs(step - ref.epsilon) - tol for step, tol in zip(steps, bound)) < 0, i
            decided_by_rounding += 1
            _sync_rls(fast, ref)
            continue
        assert np.abs(a.contact_force_S - b.contact_force_S).max() <= bound[0], i
        assert np.abs(a.contact_torque_S - b.contact_torque_S).max() <= 10 * (bound[0] + bound[1]), i
        for s_ref, s_fast, tol in ((ref.force, fast.force, bound[0]), (ref.torque, fast.torque, bound[1])):
            assert np.abs(s_ref.x - s_fast.x).max() <= tol, i
        # the force stage's sums get the same terms (the torque stage's A_k is built from the bias just solved for)
        L_ref, L_fast = ref.force.Lambda, fast.force.Lambda
        assert np.abs(L_ref - L_fast).max() <= 1e-13 * np.abs(L_ref).max(), i
        assert np.abs(ref.force.eta - fast.force.eta).max() <= 1e-13 * np.abs(ref.force.eta).max(), i
        assert (ref.force.updates, ref.torque.updates) == (fast.force.updates, fast.torque.updates)
    assert decided_by_rounding <= 10
    assert ref.converged_force and ref.converged_torque  # the run went through convergence


@pytest.mark.parametrize("form", ["printed", INFO])
@pytest.mark.parametrize("size", [7, 1024])
def test_rls_kernel_gives_the_same_bits_in_any_block_size(sim, size, form):
    one, blocks = RLSEstimator(covariance_update=form), RLSEstimator(covariance_update=form)
    a = [one.update_block(sim.subset(slice(i, i + 1))) for i in range(len(sim))]
    b = [blocks.update_block(sim.subset(slice(i, i + size))) for i in range(0, len(sim), size)]
    for key in KEYS:
        assert np.array_equal(
            np.concatenate([getattr(p, key) for p in a]), np.concatenate([getattr(p, key) for p in b])
        ), key
    assert one.params() == blocks.params() and one.cov_diag() == blocks.cov_diag()
    assert (one.force.updates, one.torque.updates) == (blocks.force.updates, blocks.torque.updates)


def test_rls_kernel_free_run_sample_by_sample_takes_the_same_decisions(sim, numpy_reference):
    """Sample by sample (the live loop's blocks of 1) the two paths solve the same Λ with the same
    LAPACK routine: on this tour every flag agrees and the parameters end within 1e-12."""
    ref = RLSEstimator(kernel="numpy", covariance_update=INFO)
    fast = RLSEstimator(kernel="numba", covariance_update=INFO)
    a, b = run_blocks(ref, sim, 1), run_blocks(fast, sim, 1)
    for key in KEYS[2:]:
        assert np.array_equal(a[key], b[key]), key
    p, q = ref.params(), fast.params()
    for key in p:
        assert np.allclose(p[key], q[key], rtol=1e-12, atol=1e-12), key
    assert np.allclose(ref.cov_diag(), fast.cov_diag(), rtol=1e-9)
    assert (ref.force.updates, ref.torque.updates) == (fast.force.updates, fast.torque.updates)


def test_rls_kernel_free_run_ends_at_the_same_parameters(sim, numpy_reference):
    """Without lockstep the runs part at a flag decided within rounding, and meet again: the same
    samples' least-squares solution once both stages have converged for good."""
    out = {}
    for kernel in ("numpy", "numba"):
        est = RLSEstimator(kernel=kernel, covariance_update=INFO)
        for i in range(0, len(sim), 7):
            est.update_block(sim.subset(slice(i, i + 7)))
        out[kernel] = est
    p, q = out["numpy"].params(), out["numba"].params()
    for key in p:
        assert np.allclose(p[key], q[key], rtol=0, atol=1e-3), key
    assert np.allclose(out["numpy"].cov_diag(), out["numba"].cov_diag(), rtol=1e-2)


def test_rls_kernel_option_is_validated(numpy_reference):
    with pytest.raises(ValueError, match=r"^kernel: "):
        RLSEstimator(kernel="cuda")
    assert RLSEstimator(kernel="numpy").kernel == "numpy"
    assert RLSEstimator().kernel == "numba"


def test_rls_parameter_std_kernel_matches_the_inverse(sim):
    """What the haptic gate reads every tick (``force_parameter_std``): the compiled path's diag(Λ⁻¹) by
    Cholesky against ``np.linalg.inv`` (``RecursiveLeastSquares.P``), along the tour from P0 through the
    motion's first, badly conditioned poses to well identified: agreeing to the inverses' forward error
    bound, 1e-14·cond(Λ) relative; a Λ that is not positive definite goes to ``P`` (inf when singular)."""
    from hapticlab.plugins.estimators.rls.information_form_kernel import inverse_diag

    est = RLSEstimator(kernel="numba", covariance_update=INFO)
    checked = 0
    for i in range(0, 3000, 100):
        ref = np.sqrt(np.diag(np.linalg.inv(est.force.Lambda)))
        bound = 1e-14 * np.linalg.cond(est.force.Lambda)
        assert np.allclose(est.force_parameter_std(), ref, rtol=bound, atol=0.0), (i, bound)
        est.update_block(sim.subset(slice(i, i + 100)))
        checked += 1
    assert checked == 30 and est.force_parameter_std().max() < 0.01  # the tour identified the force stage
    singular = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 0.0])  # nothing known of bias_force_S's z
    assert not inverse_diag(singular, np.empty((6, 6)), np.empty(6))
    np.copyto(est.force.Lambda, singular)
    assert np.isinf(est.force_parameter_std()).all()  # as P says: inf where Λ cannot be inverted


def _tilted_tour(duration_s: float):
    """The simulated tour (seed 1, the static model) with the robot's base tilted 1.5° against gravity."""
    from hapticlab.plugins.simworld import SimWorld
    from hapticlab.plugins.simworld.params import RobotParams
    from hapticlab.sessions.bench.simulation import simulate

    tilt = np.radians(1.5) * np.array([0.6, -0.8, 0.0])
    block, _ = simulate(SimWorld(robot=RobotParams(base_tilt_BG=tilt), seed=1, inertia=False), duration_s, 1000.0)
    return block


@pytest.mark.parametrize("size", [1, 7])
def test_the_default_is_algorithm1_number_for_number(size):
    """``rls`` with its defaults (the printed update, compiled) against ``algorithm1`` (the paper's lines over
    whole arrays, numpy), from the same random initial estimates, on 4 s of a tilted base: every convergence
    decision and every contact flag the same, x and P bit for bit. The kernel sums each small product in the
    order numpy's BLAS does on this machine (OpenBLAS, x86-64 with FMA: ``covariance_form_kernel``); where a
    BLAS sums otherwise an ulp here and there would move the printed form's P, and this test says so."""
    from hapticlab.plugins.estimators.rls.algorithm1 import algorithm1

    block = _tilted_tour(4.0)
    est = RLSEstimator()
    out = run_blocks(est, block, size)
    rng = np.random.default_rng(0)  # the estimator's own draws (seed 0): force stage, then torque stage
    x0_force, x0_torque = rng.standard_normal(6), rng.standard_normal(6)
    ref = algorithm1(block.force_S, block.torque_S, block.R_EB, 1.0, 0.1, x0_force, x0_torque)
    assert ref["converged_force"].any() and ref["converged_torque"].any()  # the run goes through convergence
    for key in ("converged_force", "converged_torque"):
        assert np.array_equal(out[key], ref[key]), key
    assert np.array_equal(out["contact"], ~ref["updated_force"] | (ref["converged_force"] & ~ref["updated_torque"]))
    assert np.array_equal(est.force.x, ref["x_force"][-1]) and np.array_equal(est.torque.x, ref["x_torque"][-1])
    # the contact wrench is written differently (a cross product against the skew matrix): ulps of the readings
    assert np.abs(out["contact_force_S"] - ref["contact_force_S"]).max() < 1e-11
    assert np.abs(out["contact_torque_S"] - ref["contact_torque_S"]).max() < 1e-11


def test_the_information_form_decides_convergence_elsewhere_on_the_same_recording():
    """Why it is not the default: on the same recording the information form (the paper's estimate in exact
    arithmetic) raises its flags at other samples than Algorithm 1 does (the printed update's rounding is part
    of the paper's numbers), though the two estimates end within a hundredth of a newton."""
    from hapticlab.plugins.estimators.rls.algorithm1 import algorithm1

    block = _tilted_tour(4.0)
    info = run_blocks(RLSEstimator(covariance_update="information"), block, 1)
    rng = np.random.default_rng(0)
    x0_force, x0_torque = rng.standard_normal(6), rng.standard_normal(6)
    ref = algorithm1(block.force_S, block.torque_S, block.R_EB, 1.0, 0.1, x0_force, x0_torque)
    differ = np.count_nonzero(info["converged_force"] != ref["converged_force"]) + np.count_nonzero(
        info["converged_torque"] != ref["converged_torque"]
    )
    assert differ > 0
    assert np.abs(info["contact_force_S"][-1000:] - ref["contact_force_S"][-1000:]).max() < 0.01
