"""The compiled kernels (``core.estimation.kernels``) against the numpy references they replace (issue 12).

Data: the simulated physics of ``bench paper`` (SimWorld, seeded), blocks of 1, 7 and 1024.

``rls``: not bit-for-bit. The kernel calls the same LAPACK ``dposv`` on the same Λ, but a BLAS
product (Aᵀy for a non-contiguous R_EB) may round differently by an ulp, so x differs by up to
~cond(Λ)·1e-16·‖x‖,
and on this tour cond(Λ) of the force stage reaches ~1e12 (one direction of B is barely
excited for a while): x then differs by ~1e-4 after a single update, and the convergence
test ‖Δx‖ < 1e-3 decides differently where a step lies that close to 1e-3 (4 samples of
3000). Whole runs then follow different, equally valid samples: the numpy path in blocks
of 1 and of 7 differs from itself the same way. So the kernel is held to the reference in
lockstep, one sample at a time from the reference's state, with the forward error bound of the two
solves, 1e-14·cond(Λ)·‖x‖ (a flag may differ only where the reference's step is within that bound of ε), and the
kernel must give the same bits whatever the block size (it runs sample by sample).

``kalman``: the same decisions, the same numbers to rounding. The kernel is ``plugins.estimators.kalman.stage_reference.filter6``
transcribed expression by expression and numba compiles without fast-math (no FMA contraction, no
reordering), so on one machine the two agreed to the bit; but the numpy side's matrix products go
through OpenBLAS, which picks its kernels by CPU: on an AVX-512 CPU (SkylakeX kernels) they round
differently by an ulp (1.8e-15 N at most on this tour; ``OPENBLAS_CORETYPE=Haswell`` gives the bits
back). So every flag must be identical, the numbers within :data:`ROUNDING` (N, N·m; relative for
parameters and covariances). With the noise estimated (``noise = "auto"``) the sums of diag(C P Cᵀ)
are taken in another order than numpy's einsum and that estimate feeds R back into the gain: before
convergence, with P still at the prior's 400 N², a few ulp grow to 2e-11 N on this tour
(:data:`ROUNDING_NOISE`); the flags stay identical. With bias-rate states the reference is filterpy's
filter (Joseph-form covariance update, F P Fᵀ as matrix products) and the kernel ``stage_step_rate``
(the LDLᵀ update, F's rows and columns added): the same filter, another arithmetic, ~1e-10 N apart on
this tour (:data:`ROUNDING_RATE`, as the fast path is held to filterpy); the flags identical.
"""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.bench.simulation import simulate

KEYS = ("contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque")
ROUNDING = 1e-12
"""How far the kalman kernel and the numpy reference may differ: a few ulp of BLAS rounding (see above)."""
ROUNDING_NOISE = 1e-10
ROUNDING_RATE = 1e-9
"""The same with the noise estimated: the rounding fed back through R (see above)."""
ROUNDING_WALK = 1e-9
"""With the noise estimated on a tour the model lacks a 5° mount for, and the tilt walk learnt from it: the
mount's 0.3 N error and the walk keep the gain up throughout, and the rounding fed back through R reaches
1.5e-10 N (measured); the flags and the pairs scored stay identical."""


def _same(a, b, key: str = "", tol: float = ROUNDING) -> bool:
    """Flags identical; numbers within tol (NaN where the other is NaN)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind in "biu" or key in KEYS[2:]:
        return np.array_equal(a, b)
    return a.shape == b.shape and np.allclose(a, b, rtol=tol, atol=tol, equal_nan=True)


def _same_information(a: dict, b: dict, tol: float) -> bool:
    """The identified rule's information matrices (state()["information"]), within tol of each matrix's largest
    entry: its entries are sums of C^T R^-1 C over every sample (up to ~1e8), off-diagonal ones cancelling to
    ~1, so the rounding of R (above) shows at tol of the matrix's scale, not of each entry. The same for the
    learnt tilt walk's state (state()["tilt"]["walk"]): its windows' sums of R_SB over up to ~1000 samples
    (a mount estimate's rounding in each R_SB adds up there: 3e-8 of −7.5 measured)."""
    return a.keys() == b.keys() and all(np.abs(np.subtract(a[k], b[k])).max() <= tol * np.abs(a[k]).max() for k in a)


def _same_tree(a, b, tol: float = ROUNDING) -> bool:
    """params(), cov_diag() and state() of the two: the same keys and flags, numbers within tol."""
    if isinstance(a, dict):
        return (
            isinstance(b, dict)
            and a.keys() == b.keys()
            and all(
                _same_information(a[k], b[k], tol)
                if k == "information"
                else _same_information({k: a[k]}, {k: b[k]}, tol)
                if k == "walk" and a[k] is not None
                else _same_tree(a[k], b[k], tol)
                for k in a
            )
        )
    if isinstance(a, (list, tuple)) and a and not isinstance(a[0], (int, float, bool)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(_same_tree(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, (bool, str)) or a is None:
        return a == b
    return _same(a, b, tol=tol)


@pytest.fixture(scope="module")
def sim():
    block, _ = simulate(SimWorld(seed=1, inertia=False), 3.0, 1000.0)
    return block


@pytest.fixture(scope="module")
def sim6():
    """6 s: the kalman torque stage converges after ~4 s of this tour."""
    block, _ = simulate(SimWorld(seed=1, inertia=False), 6.0, 1000.0)
    return block


def _sync_rls(dst: RLSEstimator, src: RLSEstimator) -> None:
    """dst takes src's state, in place (the kernel's arrays stay the ones it was given)."""
    for a, b in ((dst.force, src.force), (dst.torque, src.torque)):
        np.copyto(a.x, b.x)
        np.copyto(a.Lambda, b.Lambda)
        np.copyto(a.eta, b.eta)
        a.updates, a.failed = b.updates, b.failed
    dst.converged_force, dst.converged_torque = src.converged_force, src.converged_torque


def test_rls_kernel_matches_numpy_in_lockstep(sim, numpy_reference):
    ref, fast = RLSEstimator(kernel="numpy"), RLSEstimator(kernel="numba")
    decided_by_rounding = 0
    for i in range(len(sim)):
        part = sim.subset(slice(i, i + 1))
        _sync_rls(fast, ref)
        before = ref.force.x.copy(), ref.torque.x.copy()
        a, b = ref.update_block(part), fast.update_block(part)
        # the forward error of a Cholesky solve, ~3n·u·cond(Λ)·‖x‖ for each path (n = 6, u = 1.1e-16), twice;
        # the torque stage's A_k = −[f − b_f]ₓ also carries the force stage's difference in b_f
        cond_f, cond_t = np.linalg.cond(ref.force.Lambda), np.linalg.cond(ref.torque.Lambda)
        dA = np.linalg.norm(ref.force.x[3:] - fast.force.x[3:]) / np.linalg.norm(part.force_S[0] - ref.force.x[3:])
        bound = [
            1e-14 * cond_f * max(1.0, np.linalg.norm(ref.force.x)) + 1e-12,
            (1e-14 + 3 * dA) * cond_t * max(1.0, np.linalg.norm(ref.torque.x)) + 1e-12,
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


@pytest.mark.parametrize("size", [7, 1024])
def test_rls_kernel_gives_the_same_bits_in_any_block_size(sim, size):
    one, blocks = RLSEstimator(), RLSEstimator()
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
    ref, fast = RLSEstimator(kernel="numpy"), RLSEstimator(kernel="numba")
    a, b = _run(ref, sim, 1), _run(fast, sim, 1)
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
        est = RLSEstimator(kernel=kernel)
        for i in range(0, len(sim), 7):
            est.update_block(sim.subset(slice(i, i + 7)))
        out[kernel] = est
    p, q = out["numpy"].params(), out["numba"].params()
    for key in p:
        assert np.allclose(p[key], q[key], rtol=0, atol=1e-3), key
    assert np.allclose(out["numpy"].cov_diag(), out["numba"].cov_diag(), rtol=1e-2)


def test_rls_kernel_option_is_validated(numpy_reference):
    with pytest.raises(ValueError, match="^kernel: "):
        RLSEstimator(kernel="cuda")
    assert RLSEstimator(kernel="numpy").kernel == "numpy"
    assert RLSEstimator().kernel == "numba"


def _run(est, block, size):
    parts = [est.update_block(block.subset(slice(i, i + size))) for i in range(0, len(block), size)]
    return {key: np.concatenate([getattr(p, key) for p in parts]) for key in KEYS}


_REFERENCES: dict = {}


def _reference(block, options, size) -> tuple[KalmanEstimator, dict]:
    """The numpy reference over ``block`` in blocks of ``size`` with ``options``, and its outputs. With the
    noise estimated or the identified rule it runs one sample at a time whatever the block it is given, so
    every block size gives the same bits (``test_the_numpy_reference_is_the_same_at_every_block_size``): run
    once per block and options, and the compiled kernel compared with it at each size. Otherwise (a fixed
    noise with the covariance rule: per block, the inertial force from the mass before the block) per size."""
    ref = KalmanEstimator(kernel="numpy", **options)
    key = (id(block), repr(sorted(options.items())), None if ref._per_sample else size)
    if key not in _REFERENCES:
        _REFERENCES[key] = (ref, _run(ref, block, size))
    return _REFERENCES[key]


def test_the_numpy_reference_is_the_same_at_every_block_size(sim6, numpy_reference):
    runs = [_run(KalmanEstimator(kernel="numpy"), sim6.subset(slice(0, 3000)), size) for size in (1, 7, 1024)]
    for key in KEYS:
        assert np.array_equal(runs[0][key], runs[1][key]) and np.array_equal(runs[0][key], runs[2][key]), key


GAMMA = {"noise_force": 0.12, "noise_torque": 0.01, "convergence": "covariance"}
"""kalman's options before the defaults estimated the noise: the simulated Gamma's, convergence from P."""


def _tolerance(options) -> float:
    if options.get("bias_rate") or options.get("mount_rotation"):
        return ROUNDING_RATE
    return ROUNDING_NOISE if options.get("noise_force", "auto") == "auto" else ROUNDING


@pytest.mark.parametrize(
    "options",
    [
        {},
        GAMMA,
        {**GAMMA, "convergence": "identified"},
        {"convergence": "covariance"},
        {"convergence": "identified"},
        {"mount_rotation": True},
        {"convergence": "step"},
        {"time_lag_s": -0.004},
        {**GAMMA, "time_lag_s": -0.004},
        {"bias_rate": True},
        {**GAMMA, "bias_rate": True},
        {"mount_rotation": True, "bias_rate": True},
        {"mount_rotation": True, "mount_rotation_SE": [0.0, 0.05, 0.02]},
        {"bias_force_tilt_rw": 0.1},
        {**GAMMA, "convergence": "identified", "bias_force_tilt_rw": 0.03},
        {"bias_force_tilt_rw": 0.1, "convergence": "step"},
        {"bias_force_tilt_rw": 0.1, "time_lag_s": -0.004},
        {"bias_force_tilt_rw": 0.1, "mount_rotation": True, "bias_rate": True},
    ],
    ids=[
        "defaults",
        "gamma-covariance",
        "gamma-identified",
        "auto-covariance",
        "auto-identified",
        "mount",
        "step",
        "sensor-late",
        "gamma-sensor-late",
        "bias-rate",
        "gamma-bias-rate",
        "mount-bias-rate",
        "mount-from-3-deg",
        "tilt-walk",
        "gamma-tilt-walk",
        "step-tilt-walk",
        "sensor-late-tilt-walk",
        "mount-bias-rate-tilt-walk",
    ],
)
@pytest.mark.parametrize("size", [1, 7, 1024])
def test_kalman_kernel_agrees_with_numpy(sim6, size, options, numpy_reference):
    """The noise estimate and the convergence rules run in the compiled cascade (the numpy reference
    runs them one sample at a time, so every block size gives the same numbers); the paper's step rule
    runs the compiled stage filter (``filter6``). A late sensor stream (its poses interpolated per block
    before the cascade, its first 4 ms unused) runs in the cascade too, and so do bias-rate states
    (``stage_step_rate`` against filterpy's filter) and a mount estimate (``stage_step_mount`` against
    ``plugins.estimators.kalman.mount_stage.MountStage``'s EKF, from the identity or from a 3° mount, with and without rates); and
    the bias's tilt walk (``add_tilt_noise``, the tilt from ``tilt_step``) with the defaults, the noise given,
    the step rule, a late sensor stream, and a mount with rates."""
    (ref, a), fast = _reference(sim6, options, size), KalmanEstimator(kernel="numba", **options)
    assert fast._cascade == (options.get("convergence") != "step")
    b = _run(fast, sim6, size)
    tol = _tolerance(options)
    for key in KEYS:
        assert _same(a[key], b[key], key, tol), key
    assert a["converged_force"].any() and a["converged_torque"].any()
    assert _same_tree(ref.params(), fast.params(), tol) and _same_tree(ref.cov_diag(), fast.cov_diag(), tol)
    assert _same_tree(ref.state(), fast.state(), tol)
    assert np.allclose(ref.force_parameter_std(), fast.force_parameter_std(), rtol=1e-9)
    assert (ref.first_converged_force, ref.first_converged_torque) == (
        fast.first_converged_force,
        fast.first_converged_torque,
    )


@pytest.fixture(scope="module")
def sim_mounted():
    """8 s of a tour whose sensor is mounted 5° off: an error that moves with the tilt, for the walk to learn."""
    from hapticlab.sessions.bench import family as familybench

    return familybench.tour(8.0, sensor={"mount_rotation": familybench.MOUNT_ROTATION_SE})[1]


@pytest.mark.parametrize(
    "options",
    [{}, GAMMA, {"convergence": "step"}, {"bias_rate": True}, {"mount_rotation": True}],
    ids=["auto", "gamma-covariance", "step", "bias-rate", "mount"],
)
@pytest.mark.parametrize("size", [1, 64])
def test_a_learnt_tilt_walk_is_the_reference_s(sim_mounted, size, options, numpy_reference):
    """The tilt walk learnt from the data (``bias_force_tilt_rw = "auto"``, ``plugins.estimators.kalman.tilt_walk_kernel``) in the
    compiled cascade and in the numpy reference (``learn_tilt_walk`` as Python, after each sample: the
    reference filters one sample at a time with it, so every block size gives its numbers), on a tour with a
    5° mount the model lacks, from which both learn a walk: the same pairs scored, the same flags, the walk
    and the wrench within rounding. (With the step rule both sides run the learner as Python around the
    compiled stage filter.)"""
    options = {**options, "bias_force_tilt_rw": "auto"}
    (ref, a), fast = _reference(sim_mounted, options, size), KalmanEstimator(kernel="numba", **options)
    b = _run(fast, sim_mounted, size)
    tol = max(_tolerance(options), ROUNDING_WALK if options.get("noise_force", "auto") == "auto" else 0.0)
    assert fast._cascade == (options.get("convergence") != "step")
    for key in KEYS:
        assert _same(a[key], b[key], key, tol), key
    learnt = ref.params()["bias_force_tilt_rw"][0]
    assert ref.params()["tilt_walk_pairs"] == fast.params()["tilt_walk_pairs"] and learnt > 0.02
    assert _same_tree(ref.params(), fast.params(), tol) and _same_tree(ref.state(), fast.state(), tol)


def test_the_learner_s_step_test_is_the_reference_s(numpy_reference):
    """``learn_tilt_walk`` compiled and as Python (``py_func``, which the numpy reference runs) on the same samples,
    with 0.5 N steps inside some windows (a light touch the gate took in): the same state to the bit, windows
    left out for their step, and the test's share of failed windows the same."""
    from hapticlab.core.frames import matrix_from_rotvec
    from hapticlab.plugins.estimators.kalman import tilt_walk_kernel as tilt_walk

    rng = np.random.default_rng(31)
    n, rate = 20000, 1000.0
    weight_B = np.array([0.02, -0.03, -3.4])
    g_B = weight_B / np.linalg.norm(weight_B)
    t = np.arange(n) / rate
    angle = 0.35 * t  # rad: about 20°/s, about one window a second
    axis = np.array([np.cos(0.1 * t), np.sin(0.1 * t), np.zeros(n)]).T  # (a turn whose axis drifts)
    R_SB = np.array([matrix_from_rotvec(a * u) for a, u in zip(angle, axis)])
    touching = (t % 4.0 > 1.3) & (t % 4.0 < 3.3)  # 2 s in every 4: edges fall inside windows
    y = R_SB @ weight_B + np.array([1.0, 2.0, 0.5]) + rng.normal(0.0, 0.12, (n, 3)) + 0.5 * touching[:, None]
    a = np.concatenate([weight_B, [1.0, 2.0, 0.5]])
    fast, ref = tilt_walk.new_state(), tilt_walk.new_state()
    for k in range(n):
        q_fast = tilt_walk.learn_tilt_walk(fast, y[k], R_SB[k], a, g_B, t[k], False, 0.0)
        q_ref = tilt_walk.learn_tilt_walk.py_func(ref, y[k], R_SB[k], a, g_B, t[k], False, 0.0)
        assert q_fast == q_ref, k
    print(
        f"\nstep test: share of failed windows {fast[tilt_walk.TW_STEP_RATE]:.2f} over "
        f"{fast[tilt_walk.TW_STEP_N]:.0f}; pairs scored {fast[tilt_walk.TW_PAIRS]:.0f}; walk {np.sqrt(q_fast):.4f}"
    )
    assert np.array_equal(fast, ref)
    assert 0.0 < fast[tilt_walk.TW_STEP_RATE] < tilt_walk.STEP_STAND_DOWN  # windows left out for a step


@pytest.mark.parametrize("size", [1, 7])
def test_a_late_sensor_streams_poses_and_positions_are_interpolated_as_the_reference_does(
    sim_inertia, size, numpy_reference
):
    """The live aligner's blocks carry quaternions and positions: a late sensor stream's poses and positions
    at t + τ come from the compiled interpolation (``core.aligner_kernel``) against numpy's slerp and lerp
    (libm's sin/acos: not to the bit), with the inertial force from those positions. The flags the same, the
    wrench within ROUNDING_NOISE."""
    import dataclasses

    from hapticlab.core.frames import quat_wxyz_from_matrix

    t = sim_inertia.t_ns * 1e-9
    p_BoEo_B = np.column_stack([0.4 + 0.05 * np.sin(1.3 * t), 0.1 * np.cos(0.7 * t), 0.3 + 0.02 * t])  # m
    block = dataclasses.replace(
        sim_inertia, quat_BE=quat_wxyz_from_matrix(sim_inertia.R_EB.transpose(0, 2, 1)), p_BoEo_B=p_BoEo_B
    )
    options = {"inertia": True, "time_lag_s": -0.004}
    a, b = (_run(KalmanEstimator(kernel=kernel, **options), block, size) for kernel in ("numpy", "numba"))
    for key in KEYS:
        assert _same(a[key], b[key], key, ROUNDING_NOISE), key
    assert a["converged_force"].any()


@pytest.mark.parametrize("size", [7, 1024])
def test_a_compiled_mount_estimate_is_the_same_at_every_block_size(sim6, size, numpy_reference):
    """With the noise given the numpy reference filters a block and then turns every sample of it through
    the mount estimated over the whole block (0.21 N apart from sample by sample, in blocks of 7, while the
    mount converges); the compiled cascade turns each sample through the mount as it is after that sample,
    the reference run one sample at a time, whatever the block size (so a session's live blocks and an
    offline run agree)."""
    options = {**GAMMA, "mount_rotation": True}
    (_, a), fast = _reference(sim6, options, 1), KalmanEstimator(kernel="numba", **options)
    b = _run(fast, sim6, size)
    for key in KEYS:
        assert _same(a[key], b[key], key, ROUNDING_RATE), key
    block_wise = _reference(sim6, options, size)[1]  # the reference in blocks: not the same
    assert np.abs(block_wise["contact_force_S"] - a["contact_force_S"]).max() > 1e-3


@pytest.fixture(scope="module")
def sim_inertia():
    block, _ = simulate(SimWorld(seed=1, inertia=True), 6.0, 1000.0)
    return block


@pytest.mark.parametrize(
    "options, tol",
    [
        ({**GAMMA, "inertia": True}, 1e-12),
        ({**GAMMA, "inertia": True, "time_lag_s": 0.004}, 1e-9),
        ({"inertia": True}, ROUNDING_NOISE),
        ({"inertia": True, "time_lag_s": 0.004}, 1e-9),
        ({"inertia": True, "time_lag_s": -0.004}, ROUNDING_NOISE),
        ({"inertia": True, "bias_rate": True}, ROUNDING_RATE),
    ],
    ids=["gamma-inertia", "gamma-inertia-lag", "inertia", "inertia-lag", "inertia-sensor-late", "inertia-bias-rate"],
)
@pytest.mark.parametrize("size", [1, 7, 1024])
def test_kalman_inertia_kernel_matches_numpy(sim_inertia, size, options, tol, numpy_reference):
    """Not to the bit: the derivatives' window sums are taken in order, numpy's pairwise (see
    plugins/estimators/kalman/derivatives_kernel.py); ω agrees to ~1e-13 relative, α to ~1e-9 of its largest value (a second
    difference over 20 ms), the inertial force (0.35 kg) to ~1e-14 N. The filter carries that through:
    1e-12 N and N·m on the contact wrench (measured 2e-14), the same flags. With a kinematics lag the
    pose itself is extrapolated by ω τ + ½ α τ², so α's difference reaches R_EB: 1e-9 (measured 6e-11). With
    the defaults (the noise estimated) the rounding fed back through R: ROUNDING_NOISE."""
    (ref, a), fast = _reference(sim_inertia, options, size), KalmanEstimator(kernel="numba", **options)
    assert fast._cascade
    b = _run(fast, sim_inertia, size)
    for key in KEYS[2:]:
        assert np.array_equal(a[key], b[key]), key
    for key in KEYS[:2]:
        assert np.abs(a[key] - b[key]).max() <= tol, key
    assert a["converged_force"].any() and a["converged_torque"].any()
    p, q = ref.params(), fast.params()
    for key in p:
        assert np.abs(np.subtract(p[key], q[key])).max() <= tol, key
    assert np.allclose(ref.cov_diag(), fast.cov_diag(), rtol=10 * tol, atol=0)


@pytest.mark.parametrize("size", [1, 7, 1024])
def test_motion_derivatives_kernel_matches_numpy(sim_inertia, size):
    from hapticlab.core.frames import quat_wxyz_from_matrix
    from hapticlab.plugins.estimators.kalman.derivatives import MotionDerivatives
    from hapticlab.plugins.estimators.kalman.derivatives_kernel import CompiledMotionDerivatives

    block = sim_inertia.subset(slice(0, 2000))
    t = block.t_ns * 1e-9
    p = np.column_stack([0.1 * np.sin(3 * t), 0.05 * np.cos(2 * t), 0.02 * t * t])  # m
    p[500] = np.nan  # a position missing: left out of its windows
    q = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
    for quat in (None, q):  # from R_EB (the kernel's own Shepperd, the same bits) or given
        ref, fast = MotionDerivatives(0.02), CompiledMotionDerivatives(0.02)
        out = []
        for est in (ref, fast):
            parts = [
                est.update(
                    block.t_ns[i : i + size],
                    None if quat is None else quat[i : i + size],
                    p[i : i + size],
                    R_EB=block.R_EB[i : i + size],
                )
                for i in range(0, len(block), size)
            ]
            out.append([np.concatenate([part[j] for part in parts]) for j in range(3)])
        (w, alpha, a), (w2, alpha2, a2) = out
        assert np.abs(w - w2).max() <= 1e-12 * np.abs(w).max()
        assert np.abs(alpha - alpha2).max() <= 1e-8 * np.abs(alpha).max()
        assert np.abs(a - a2).max() <= 1e-8 * np.abs(a).max()
        assert np.abs(a).max() > 0 and np.array_equal(a == 0, a2 == 0)  # the same samples fitted


@pytest.mark.parametrize("size", [1, 7])
def test_kernels_refuse_the_same_samples_and_keep_the_state(sim, size, numpy_reference):
    block = sim.subset(np.arange(1400))  # a copy (a slice is a view): the module's tour must stay clean
    block.force_S[700, 1] = np.nan
    block.torque_S[703] = np.inf
    block.R_EB[1100] *= 2.0  # not a rotation
    bad = np.array([700, 703, 1100])
    clean = block.subset(np.setdiff1d(np.arange(len(block)), bad))
    for make in (RLSEstimator, KalmanEstimator, lambda **kw: KalmanEstimator(**GAMMA, **kw)):
        fast, without = make(kernel="numba"), make(kernel="numba")
        b = _run(fast, block, size)
        assert fast.refused_samples == 3
        assert np.isnan(b["contact_force_S"][bad]).all() and not b["contact"][bad].any()
        c = _run(without, clean, size)  # as if the bad samples had never arrived
        for key in KEYS:
            assert np.array_equal(np.delete(b[key], bad, axis=0), c[key]), (make, key)
        assert fast.params() == without.params() and fast.cov_diag() == without.cov_diag()
        if make is not RLSEstimator:  # and the numpy reference does the same, to rounding
            ref = make(kernel="numpy")
            a = _run(ref, block, size)
            assert ref.refused_samples == 3
            for key in KEYS:
                assert _same(a[key], b[key], key, _tolerance({} if make is KalmanEstimator else GAMMA)), key


@pytest.mark.parametrize("options", [{}, GAMMA], ids=["defaults", "gamma-covariance"])
def test_kalman_restart_and_payload_paths_use_the_kernel_and_agree(sim, options, numpy_reference):
    ref, fast = KalmanEstimator(kernel="numpy", **options), KalmanEstimator(kernel="numba", **options)
    for est in (ref, fast):
        est.update_block(sim.subset(slice(0, 1500)))
        est.reidentify_bias("test")
    a, b = _run(ref, sim.subset(slice(1500, 3000)), 1), _run(fast, sim.subset(slice(1500, 3000)), 1)
    tol = _tolerance(options)
    for key in KEYS:
        assert _same(a[key], b[key], key, tol), key
    assert _same_tree(ref.state(), fast.state(), tol)


def test_kalman_kernel_option_is_validated(numpy_reference):
    with pytest.raises(ValueError, match="^kernel: "):
        KalmanEstimator(kernel="fortran")
    assert KalmanEstimator(kernel="numpy").method is None
    assert KalmanEstimator().method == "numba"
    assert KalmanEstimator(implementation="filterpy").method == "filterpy"
    assert KalmanEstimator(bias_rate=True).method is None


def test_quaternion_kernel_gives_the_numpy_bits():
    from scipy.spatial.transform import Rotation

    from hapticlab.core.frames import quat_wxyz_from_matrix
    from hapticlab.plugins.estimators.kalman.derivatives_kernel import quat_BE_from_R_EB

    R_EB = Rotation.random(5000, random_state=3).as_matrix()
    R_EB[:4] = [np.eye(3), np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1])]  # each branch
    out = np.empty((len(R_EB), 4))
    quat_BE_from_R_EB(R_EB, out)
    assert np.array_equal(out, quat_wxyz_from_matrix(R_EB.transpose(0, 2, 1)))


class _Range:
    """A sensor's range (HasRange), N and N·m."""

    range_force_S = np.array([40.0, 40.0, 120.0])
    range_torque_S = np.array([2.0, 2.0, 2.5])


def _spoilt(block, rng, size: int):
    """``size`` consecutive samples of the tour with faults a real stream has, each in some blocks: NaN and inf
    in the wrench, orientation and position, stale orientations, bad status words, readings beyond the range
    (with a good status and with a bad one)."""
    from dataclasses import replace

    start = int(rng.integers(0, len(block) - size))
    b = block.subset(slice(start, start + size))
    b = replace(
        b,
        force_S=b.force_S.copy(),
        torque_S=b.torque_S.copy(),
        R_EB=b.R_EB.copy(),
        stale=b.stale.copy(),
        status=b.status.copy(),
        p_BoEo_B=None if rng.random() < 0.3 else rng.normal(0.0, 0.3, (size, 3)),
    )
    for _ in range(int(rng.integers(0, 3))):
        i, k = int(rng.integers(size)), int(rng.integers(3))
        fault = int(rng.integers(7))
        if fault == 0:
            b.force_S[i, k] = rng.choice([np.nan, np.inf, -np.inf])
        elif fault == 1:
            b.torque_S[i, k] = rng.choice([np.nan, np.inf])
        elif fault == 2:
            b.R_EB[i, k, int(rng.integers(3))] = np.nan
        elif fault == 3 and b.p_BoEo_B is not None:
            b.p_BoEo_B[i, k] = np.inf
        elif fault == 4:
            b.stale[i] = True
        elif fault == 5:
            b.status[i] = int(rng.choice([1, 2, 1 << 16]))
        else:
            (b.force_S if rng.random() < 0.5 else b.torque_S)[i, k] = rng.choice([-1.0, 1.0]) * 500.0
    return b


@pytest.mark.parametrize("size", [1, 7, 64])
def test_screen_kernel_gives_the_reference_s_masks_and_reason(sim, size):
    """The live loop's compiled screen against ``AlignedSamples.usable``, ``implausible`` and ``data_reason``, on
    blocks of the tour spoilt at random (seeded): the same masks and the same reason, with and without a range."""
    from hapticlab.sessions.live.gate import data_reason, implausible, screen

    rng = np.random.default_rng(size)
    reasons = set()
    for _ in range(400):
        block = _spoilt(sim, rng, size)
        for sensor in (_Range(), None):
            beyond = implausible(block, sensor)
            usable = block.usable & ~beyond
            reason = data_reason(block, usable, beyond)
            got = screen(block, sensor)
            assert np.array_equal(got[0], usable) and np.array_equal(got[1], beyond) and got[2] == reason
            reasons.add(reason)
    assert reasons == {
        "",
        "implausible sensor reading (beyond its range)",
        "stale kinematics",
        "sensor saturated or in error",
        "non-finite sensor reading",
    }  # every branch was taken


def test_constant_var_kernel_matches_numpy(sim6, numpy_reference):
    """What the motion identifies of a stage's constant (params' gravity_force_B_std and cog_S_std, the gate's
    std): the kernel's Cholesky against ``plugins.estimators.kalman.identified.constant_var``'s inverse, along the tour (Λ from a
    yaw-free start to well identified) and for a Λ that is not positive definite (inf). Two ways of inverting
    Λ agree to its forward error bound, 1e-14·cond(Λ) relative (cond reaches ~4e7 while the start's
    motion leaves gravity's horizontal part unseen)."""
    from hapticlab.plugins.estimators.kalman import identified
    from hapticlab.plugins.estimators.kalman.identified_kernel import constant_var3

    est = KalmanEstimator(kernel="numpy")
    L = np.empty((6, 6))
    checked = 0
    for i in range(0, 6000, 250):
        est.update_block(sim6.subset(slice(i, i + 250)))
        for stage in ("force", "torque"):
            info = est._information[stage]
            ref = identified.constant_var(info)
            bound = 1e-14 * np.linalg.cond(info)
            assert np.allclose(constant_var3(info, L), ref, rtol=bound, atol=0.0), (i, stage, bound)
            checked += 1
    assert checked == 48
    singular = np.zeros((6, 6))
    singular[3:, 3:] = np.eye(3)  # nothing known of the constant
    assert constant_var3(singular, L) == (np.inf, np.inf, np.inf)


def test_rls_parameter_std_kernel_matches_the_inverse(sim):
    """What the haptic gate reads every tick (``force_parameter_std``): the compiled path's diag(Λ⁻¹) by
    Cholesky against ``np.linalg.inv`` (``RecursiveLeastSquares.P``), along the tour from P0 through the
    motion's first, badly conditioned poses to well identified: agreeing to the inverses' forward error
    bound, 1e-14·cond(Λ) relative; a Λ that is not positive definite goes to ``P`` (inf when singular)."""
    from hapticlab.plugins.estimators.rls.information_form_kernel import inverse_diag

    est = RLSEstimator(kernel="numba")
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
