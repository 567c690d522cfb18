"""The ``kalman`` estimator's compiled kernels (the cascade, the stage filter, the tilt walk's learner, the motion
derivatives and the inertial force, the identified constant's variance, the quaternion) against the numpy reference,
on the simulated tour of ``bench paper`` (``kernel_tour``, tests/helpers.py) and on two others (tool inertia, a 5°
mount), in blocks of 1, 7 and 1024.

The same decisions, the same numbers to rounding. The kernel is ``plugins.estimators.kalman.stage_reference.filter6``
transcribed expression by expression and numba compiles without fast-math (no FMA contraction, no reordering), so
on one machine the two agreed to the bit; but the numpy side's matrix products go through OpenBLAS, which picks
its kernels by CPU: on an AVX-512 CPU (SkylakeX kernels) they round differently by an ulp (1.8e-15 N at most on
this tour; ``OPENBLAS_CORETYPE=Haswell`` gives the bits back). So every flag must be identical, the numbers
within ``ROUNDING`` (tests/helpers.py: N, N·m; relative for parameters and covariances). With the noise estimated
(``noise = "auto"``) the sums of diag(C P Cᵀ) are taken in another order than numpy's einsum and that estimate
feeds R back into the gain: before convergence, with P still at the prior's 400 N², a few ulp grow to 2e-11 N on
this tour (``ROUNDING_NOISE``); the flags stay identical. With bias-rate states the reference is filterpy's filter
(Joseph-form covariance update, F P Fᵀ as matrix products) and the kernel ``stage_step_rate`` (the LDLᵀ update,
F's rows and columns added): the same filter, another arithmetic, ~1e-10 N apart on this tour (``ROUNDING_RATE``,
as the fast path is held to filterpy); the flags identical.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import GAMMA, KEYS, ROUNDING_NOISE, ROUNDING_RATE, kalman_tolerance, run_blocks, same, same_tree

from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.simworld import SimWorld
from hapticlab.sessions.bench.simulation import simulate

ROUNDING_WALK = 1e-9
"""With the noise estimated on a tour the model lacks a 5° mount for, and the tilt walk learnt from it: the
mount's 0.3 N error and the walk keep the gain up throughout, and the rounding fed back through R reaches
1.5e-10 N (measured); the flags and the pairs scored stay identical."""


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
        _REFERENCES[key] = (ref, run_blocks(ref, block, size))
    return _REFERENCES[key]


def test_the_numpy_reference_is_the_same_at_every_block_size(sim6, numpy_reference):
    runs = [run_blocks(KalmanEstimator(kernel="numpy"), sim6.subset(slice(0, 3000)), size) for size in (1, 7, 1024)]
    for key in KEYS:
        assert np.array_equal(runs[0][key], runs[1][key]) and np.array_equal(runs[0][key], runs[2][key]), key


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
    ``plugins.estimators.kalman.mount_stage.MountStage``'s EKF, from the identity or from a 3° mount, with and without
    rates); and the bias's tilt walk (``add_tilt_noise``, the tilt from ``tilt_step``) with the defaults, the noise
    given, the step rule, a late sensor stream, and a mount with rates."""
    (ref, a), fast = _reference(sim6, options, size), KalmanEstimator(kernel="numba", **options)
    assert fast._cascade == (options.get("convergence") != "step")
    b = run_blocks(fast, sim6, size)
    tol = kalman_tolerance(options)
    for key in KEYS:
        assert same(a[key], b[key], key, tol), key
    assert a["converged_force"].any() and a["converged_torque"].any()
    assert same_tree(ref.params(), fast.params(), tol) and same_tree(ref.cov_diag(), fast.cov_diag(), tol)
    assert same_tree(ref.state(), fast.state(), tol)
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
    """The tilt walk learnt from the data (``bias_force_tilt_rw = "auto"``,
    ``plugins.estimators.kalman.tilt_walk_kernel``) in the compiled cascade and in the numpy reference
    (``learn_tilt_walk`` as Python, after each sample: the reference filters one sample at a time with it, so every
    block size gives its numbers), on a tour with a 5° mount the model lacks, from which both learn a walk: the same
    pairs scored, the same flags, the walk and the wrench within rounding. (With the step rule both sides run the
    learner as Python around the compiled stage filter.)"""
    options = {**options, "bias_force_tilt_rw": "auto"}
    (ref, a), fast = _reference(sim_mounted, options, size), KalmanEstimator(kernel="numba", **options)
    b = run_blocks(fast, sim_mounted, size)
    tol = max(kalman_tolerance(options), ROUNDING_WALK if options.get("noise_force", "auto") == "auto" else 0.0)
    assert fast._cascade == (options.get("convergence") != "step")
    for key in KEYS:
        assert same(a[key], b[key], key, tol), key
    learnt = ref.params()["bias_force_tilt_rw"][0]
    assert ref.params()["tilt_walk_pairs"] == fast.params()["tilt_walk_pairs"] and learnt > 0.02
    assert same_tree(ref.params(), fast.params(), tol) and same_tree(ref.state(), fast.state(), tol)


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
    a, b = (run_blocks(KalmanEstimator(kernel=kernel, **options), block, size) for kernel in ("numpy", "numba"))
    for key in KEYS:
        assert same(a[key], b[key], key, ROUNDING_NOISE), key
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
    b = run_blocks(fast, sim6, size)
    for key in KEYS:
        assert same(a[key], b[key], key, ROUNDING_RATE), key
    block_wise = _reference(sim6, options, size)[1]  # the reference in blocks: not the same
    assert np.abs(block_wise["contact_force_S"] - a["contact_force_S"]).max() > 1e-3


@pytest.fixture(scope="module")
def sim_inertia():
    block, _ = simulate(SimWorld(seed=1, inertia=True), 6.0, 1000.0)
    return block


@pytest.mark.parametrize(
    ("options", "tol"),
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
    plugins/estimators/kalman/derivatives_kernel.py); ω agrees to ~1e-13 relative, α to ~1e-9 of its largest value (a
    second difference over 20 ms), the inertial force (0.35 kg) to ~1e-14 N. The filter carries that through:
    1e-12 N and N·m on the contact wrench (measured 2e-14), the same flags. With a kinematics lag the
    pose itself is extrapolated by ω τ + ½ α τ², so α's difference reaches R_EB: 1e-9 (measured 6e-11). With
    the defaults (the noise estimated) the rounding fed back through R: ROUNDING_NOISE."""
    (ref, a), fast = _reference(sim_inertia, options, size), KalmanEstimator(kernel="numba", **options)
    assert fast._cascade
    b = run_blocks(fast, sim_inertia, size)
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


@pytest.mark.parametrize("options", [{}, GAMMA], ids=["defaults", "gamma-covariance"])
def test_kalman_restart_and_payload_paths_use_the_kernel_and_agree(sim, options, numpy_reference):
    ref, fast = KalmanEstimator(kernel="numpy", **options), KalmanEstimator(kernel="numba", **options)
    for est in (ref, fast):
        est.update_block(sim.subset(slice(0, 1500)))
        est.reidentify_bias("test")
    a, b = run_blocks(ref, sim.subset(slice(1500, 3000)), 1), run_blocks(fast, sim.subset(slice(1500, 3000)), 1)
    tol = kalman_tolerance(options)
    for key in KEYS:
        assert same(a[key], b[key], key, tol), key
    assert same_tree(ref.state(), fast.state(), tol)


def test_kalman_kernel_option_is_validated(numpy_reference):
    with pytest.raises(ValueError, match=r"^kernel: "):
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


def test_constant_var_kernel_matches_numpy(sim6, numpy_reference):
    """What the motion identifies of a stage's constant (params' gravity_force_B_std and cog_S_std, the gate's
    std): the kernel's Cholesky against ``plugins.estimators.kalman.identified.constant_var``'s inverse, along the tour
    (Λ from a yaw-free start to well identified) and for a Λ that is not positive definite (inf). Two ways of inverting
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


@pytest.mark.parametrize(
    "options",
    [
        {"inertia": True},
        {"inertia": True, "mount_rotation": True},
        {"inertia": True, "time_lag_s": 0.004},
        {"inertia": True, "time_lag_s": -0.004},
    ],
    ids=["inertia", "inertia-mount", "inertia-lag", "inertia-sensor-late"],
)
def test_a_block_subtracts_each_samples_inertial_force_as_blocks_of_one_do(options):
    """Offline (blocks of 1024) the compiled cascade computes each sample's inertial force from the mass and
    centre of mass estimated before it; the live path (blocks of one) computes it in ``_prepare`` and hands
    it to the cascade. A seeded tour that turns and translates (the tool's inertia in the physics): the same
    flags, the contact wrench and the parameters within 1e-9 (N, N·m), where the inertial force itself
    moves the contact force by more than 0.01 N."""
    from hapticlab.sessions.bench import family as familybench

    _, block = familybench.tour(8.0, seed=5, motion={"script": "random_tour", "max_translation": 0.05})
    live, offline = (KalmanEstimator(kernel="numba", **options) for _ in range(2))
    a, b = run_blocks(live, block, 1), run_blocks(offline, block, 1024)
    for key in KEYS[2:]:
        assert np.array_equal(a[key], b[key]), key
    for key in KEYS[:2]:
        assert np.abs(a[key] - b[key]).max() <= 1e-9, key
    assert a["converged_force"].any() and a["converged_torque"].any()
    p, q = live.params(), offline.params()
    for key in p:
        assert np.abs(np.subtract(p[key], q[key])).max() <= 1e-9, key
    without = run_blocks(KalmanEstimator(kernel="numba", **{**options, "inertia": False}), block, 1024)
    assert np.abs(without["contact_force_S"] - b["contact_force_S"]).max() > 0.01
