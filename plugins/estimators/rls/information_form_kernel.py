"""Algorithm 1 (the paper's gated RLS cascade) per sample, compiled: the ``rls`` estimator's hot path.

The same rules and the same information form as ``plugins.estimators.rls.information_form`` (``run_gated`` /
``_run_gated_one``), over both stages, sample by sample, in place:

    Λ_k = Λ_{k−1} + C_kᵀ C_k / r,   η_k = η_{k−1} + C_kᵀ y_k / r,   x_k = Λ_k⁻¹ η_k

with C_k = [A_k, I3]; force stage A_k = R_EB, y_k = force_S (x = [gravity_force_B,
bias_force_S]); torque stage A_k = −[force_S − bias_force_S]ₓ, y_k = torque_S
(x = [cog_S, bias_torque_S]), active where the force stage's flag is up after the
sample. Λ x = η is solved by the very LAPACK routine ``plugins.estimators.rls.information_form`` calls (scipy's
``dposv``, by its address), by LU with partial pivoting where Λ is not numerically
positive definite (``np.linalg.solve`` there); a zero pivot or a non-finite x leaves
the stage as it was (``failed``). AᵀA is rounded as BLAS rounds it (fused multiply-adds),
so Λ has the numpy path's bits.

Not bit-for-bit the numpy path everywhere: numpy's Aᵀy takes BLAS's order when the
block's R_EB is not C-contiguous, and its R_EB x (the contact wrench) always does; one
ulp there moves x by up to cond(Λ)·1e-16 (cond(Λ) reaches ~1e12 early in a tour), and
a numpy block of m > 1 samples sums C_jᵀC_j before adding Λ and solves by LU, which the
kernel, running sample by sample, does not.
tests/plugins/estimators/rls/test_kernel.py states the bounds.

Nothing is allocated: the stages' arrays are updated in place, ``work`` holds the
per-sample temporaries, the outputs are written into arrays the caller owns.

Compiled the first time, then loaded from the ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import llvmlite.ir as ir
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address, intrinsic

STATUS = (
    "converged_force",
    "converged_torque",
    "updates_force",
    "failed_force",
    "updates_torque",
    "failed_torque",
    "lapack_n",
    "lapack_nrhs",
    "lapack_info",
    "lapack_uplo",
)
"""The entries of ``status`` (int32), read and written by ``rls_cascade``: the flags, the block's counts, and
the last four are dposv's integer arguments (passed by reference)."""
SETTINGS = ("inv_r_force", "inv_r_torque", "threshold_force", "threshold_torque", "epsilon")
"""The entries of ``settings`` (float64): 1/r (1/N², 1/(N·m)²), thresholds (N, N·m), ε on ‖Δx‖₂."""


def work_arrays() -> np.ndarray:
    """(5, 6, 6) float64 scratch for ``rls_cascade`` (Λ_k, its factor, η_k, x_k, A_k)."""
    return np.zeros((5, 6, 6))


DPOSV = get_cython_function_address("scipy.linalg.cython_lapack", "dposv")
"""Address of LAPACK's dposv in scipy's library: the solver ``plugins.estimators.rls.information_form`` calls
(``scipy.linalg.lapack.dposv``)."""


def status_array() -> np.ndarray:
    """(10,) int32 ``status`` for ``rls_cascade`` (``STATUS``)."""
    return np.zeros(len(STATUS), dtype=np.int32)


@intrinsic
def _fma(typingctx, a, b, c):
    """a·b + c rounded once (what BLAS computes a 3×3 AᵀA with)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@intrinsic
def lapack8(typingctx, address, a1, a2, a3, a4, a5, a6, a7, a8):
    """Call the Fortran LAPACK routine at ``address`` (uintp) that takes eight arguments, all by reference
    (pointers, uintp each): dposv (uplo, n, nrhs, a, lda, b, ldb, info), dgesv (n, nrhs, a, lda, ipiv, b,
    ldb, info)."""
    sig = types.void(address, a1, a2, a3, a4, a5, a6, a7, a8)

    def codegen(context, builder, signature, args):
        pointer = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [pointer] * 8)
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fn, [builder.inttoptr(arg, pointer) for arg in args[1:]])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True)
def _solve(Lam, eta, L, x, lapack, dposv) -> bool:
    """x = Λ⁻¹ η for a (6, 6) Λ: LAPACK's Cholesky solve (dposv), else LU with partial pivoting; False on
    a zero pivot. ``lapack``: (4,) int32 scratch (the end of ``status``); ``dposv``: ``DPOSV``."""
    n = 6
    for i in range(n):  # Λ is symmetric: its C order is the Fortran order
        x[i] = eta[i]
        for j in range(n):
            L[i, j] = Lam[i, j]
    lapack[0], lapack[1], lapack[2], lapack[3] = 6, 1, 0, 85  # n, nrhs, info, 'U'
    address = lapack.ctypes.data
    lapack8(dposv, address + 12, address, address + 4, L.ctypes.data, address, x.ctypes.data, address, address + 8)  # type: ignore[call-arg]  # an @intrinsic is called without its typingctx
    if lapack[2] == 0:
        return True
    # not numerically positive definite: LU with partial pivoting (np.linalg.solve) on a copy of Λ (in L)
    for i in range(n):
        x[i] = eta[i]
        for j in range(n):
            L[i, j] = Lam[i, j]
    for j in range(n):
        p = j
        big = abs(L[j, j])
        for i in range(j + 1, n):
            if abs(L[i, j]) > big:
                big, p = abs(L[i, j]), i
        if L[p, j] == 0.0:
            return False  # singular (LAPACK's info > 0, numpy's LinAlgError)
        if p != j:
            for k in range(n):
                L[j, k], L[p, k] = L[p, k], L[j, k]
            x[j], x[p] = x[p], x[j]
        for i in range(j + 1, n):
            f = L[i, j] / L[j, j]
            for k in range(j + 1, n):
                L[i, k] -= f * L[j, k]
            x[i] -= f * x[j]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    return True


@njit(cache=True)
def _stage(y0, y1, y2, A, x, Lam, eta, inv_r, threshold, epsilon, converged, work, lapack, dposv):
    """One active sample of one stage (``_run_gated_one``), in place.

    Args:
        y0, y1, y2: the measurement y_k (units of y). A: (3, 3) A_k.
        x: (6,) x. Lam: (6, 6) Λ. eta: (6,) η. inv_r: 1/r. threshold: contact threshold
        on ‖C_k x_{k−1} − y_k‖. epsilon: convergence threshold on ‖Δx‖₂.
        converged: the stage's flag before the sample. work: ``work_arrays()``. lapack, dposv: see ``_solve``.

    Returns:
        (flag out, gated, converged after, failed): the row's flag (True when gated,
        False when the solve failed), and the stage's flag after the sample.
    """
    e0 = A[0, 0] * x[0] + A[0, 1] * x[1] + A[0, 2] * x[2] + x[3] - y0
    e1 = A[1, 0] * x[0] + A[1, 1] * x[1] + A[1, 2] * x[2] + x[4] - y1
    e2 = A[2, 0] * x[0] + A[2, 1] * x[1] + A[2, 2] * x[2] + x[5] - y2
    if converged and not e0 * e0 + e1 * e1 + e2 * e2 < threshold * threshold:
        return True, True, converged, False
    Lk, L, etak, xk = work[0], work[1], work[2, 0], work[2, 1]
    for i in range(3):  # Λ_k = Λ + CᵀC / r, CᵀC = [AᵀA, Aᵀ; A, I3]
        for j in range(3):
            AtA = _fma(A[2, i], A[2, j], _fma(A[1, i], A[1, j], A[0, i] * A[0, j]))  # as BLAS rounds it
            Lk[i, j] = Lam[i, j] + AtA * inv_r
            Lk[i, 3 + j] = Lam[i, 3 + j] + A[j, i] * inv_r
            Lk[3 + i, j] = Lam[3 + i, j] + A[i, j] * inv_r
            Lk[3 + i, 3 + j] = Lam[3 + i, 3 + j] + (1.0 if i == j else 0.0) * inv_r
    for i in range(3):  # η_k = η + Cᵀy / r
        etak[i] = eta[i] + (A[0, i] * y0 + A[1, i] * y1 + A[2, i] * y2) * inv_r
    etak[3] = eta[3] + y0 * inv_r
    etak[4] = eta[4] + y1 * inv_r
    etak[5] = eta[5] + y2 * inv_r
    if not _solve(Lk, etak, L, xk, lapack, dposv):
        return False, False, converged, True
    step2 = 0.0
    for i in range(6):
        d = xk[i] - x[i]
        step2 += d * d
    if not step2 < math.inf:  # a non-finite x: the stage stays as it was
        return False, False, converged, True
    for i in range(6):
        x[i] = xk[i]
        eta[i] = etak[i]
        for j in range(6):
            Lam[i, j] = Lk[i, j]
    converged = step2 < epsilon * epsilon
    return converged, False, converged, False


@njit(cache=True)
def torque_regressor(A_t, f0, f1, f2, x_f) -> None:
    """The torque stage's A_k = −[force_S − bias_force_S]ₓ into ``A_t`` (3, 3), from the force stage's x after the
    sample (C_k = [A_k, I3]; −0.0 on the diagonal, as −skew writes it)."""
    d0, d1, d2 = f0 - x_f[3], f1 - x_f[4], f2 - x_f[5]
    A_t[0, 0], A_t[0, 1], A_t[0, 2] = -0.0, d2, -d1
    A_t[1, 0], A_t[1, 1], A_t[1, 2] = -d2, -0.0, d0
    A_t[2, 0], A_t[2, 1], A_t[2, 2] = d1, -d0, -0.0


@njit(cache=True)
def write_contact_wrench(k, R, force_S, torque_S, x_f, x_t, contact_force_S, contact_torque_S) -> None:
    """Row ``k`` of the contact wrench at the stages' states after the sample (paper eqs. 20–21,
    ``core.estimation.model.contact_wrench``): force_S − R g − b_f, N; torque_S − cog × (R g) − b_t, N·m."""
    g0 = R[0, 0] * x_f[0] + R[0, 1] * x_f[1] + R[0, 2] * x_f[2]
    g1 = R[1, 0] * x_f[0] + R[1, 1] * x_f[1] + R[1, 2] * x_f[2]
    g2 = R[2, 0] * x_f[0] + R[2, 1] * x_f[1] + R[2, 2] * x_f[2]
    contact_force_S[k, 0] = force_S[k, 0] - g0 - x_f[3]
    contact_force_S[k, 1] = force_S[k, 1] - g1 - x_f[4]
    contact_force_S[k, 2] = force_S[k, 2] - g2 - x_f[5]
    contact_torque_S[k, 0] = torque_S[k, 0] - (x_t[1] * g2 - x_t[2] * g1) - x_t[3]
    contact_torque_S[k, 1] = torque_S[k, 1] - (x_t[2] * g0 - x_t[0] * g2) - x_t[4]
    contact_torque_S[k, 2] = torque_S[k, 2] - (x_t[0] * g1 - x_t[1] * g0) - x_t[5]


@njit(cache=True)
def rls_cascade(
    force_S, torque_S, R_EB, x_f, Lambda_f, eta_f, x_t, Lambda_t, eta_t, settings, status, work, dposv, wrench, flags
):
    """Algorithm 1 over m samples, in order: both stages updated in place, one output row per sample.

    Args:
        force_S: (m, 3) raw force, N. torque_S: (m, 3) raw torque, N·m. R_EB: (m, 3, 3).
        x_f, eta_f: (6,) and Lambda_f: (6, 6) the force stage (x = [gravity_force_B, bias_force_S], N).
        x_t, eta_t, Lambda_t: the torque stage (x = [cog_S (m), bias_torque_S (N·m)]).
        settings: (5,) float64, ``SETTINGS``. status: ``status_array()``, ``STATUS`` (flags in and out,
            counts incremented). work: ``work_arrays()``. dposv: ``DPOSV``.
        wrench: (2, m, 3) out: contact_force_S (N) and contact_torque_S (N·m) (paper eqs. 20–21).
        flags: (3, m) bool out: contact, converged_force, converged_torque.
        (Two output arrays rather than five: every argument adds to the call's cost.)
    """
    inv_r_f, inv_r_t, th_f, th_t, eps = settings[0], settings[1], settings[2], settings[3], settings[4]
    contact_force_S, contact_torque_S = wrench[0], wrench[1]
    contact, converged_force, converged_torque = flags[0], flags[1], flags[2]
    lapack = status[6:]
    conv_f = status[0] != 0
    conv_t = status[1] != 0
    A_t = work[3, :3, :3]
    for k in range(force_S.shape[0]):
        f0, f1, f2 = force_S[k, 0], force_S[k, 1], force_S[k, 2]
        R = R_EB[k]
        out_f, gated_f, conv_f, failed = _stage(
            f0, f1, f2, R, x_f, Lambda_f, eta_f, inv_r_f, th_f, eps, conv_f, work, lapack, dposv
        )
        if failed:
            status[3] += 1
        elif not gated_f:
            status[2] += 1
        gated_t = False
        if out_f:  # the torque stage sees the samples after which the force stage's flag is up
            torque_regressor(A_t, f0, f1, f2, x_f)
            out_t, gated_t, conv_t, failed = _stage(
                torque_S[k, 0],
                torque_S[k, 1],
                torque_S[k, 2],
                A_t,
                x_t,
                Lambda_t,
                eta_t,
                inv_r_t,
                th_t,
                eps,
                conv_t,
                work,
                lapack,
                dposv,
            )
            if failed:
                status[5] += 1
            elif not gated_t:
                status[4] += 1
        else:
            out_t = conv_t
        write_contact_wrench(k, R, force_S, torque_S, x_f, x_t, contact_force_S, contact_torque_S)
        contact[k] = gated_f or gated_t
        converged_force[k] = out_f
        converged_torque[k] = out_t
    status[0] = 1 if conv_f else 0
    status[1] = 1 if conv_t else 0


@njit(cache=True)
def inverse_diag(Lam, L, out) -> bool:
    """diag(Λ⁻¹) of a (6, 6) Λ into ``out`` (6,) by Cholesky, Λ = L Lᵀ (``L`` (6, 6) scratch, overwritten by
    L⁻¹): Λ⁻¹ = L⁻ᵀ L⁻¹, so (Λ⁻¹)_ii = Σ_k (L⁻¹)_ki². False (``out`` untouched) where Λ is not numerically
    positive definite; the caller inverts it as ``plugins.estimators.rls.information_form`` does
    (``RecursiveLeastSquares.P``)."""
    n = 6
    for i in range(n):
        for j in range(i + 1):
            s = Lam[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for j in range(n):  # L⁻¹ column by column, in place (forward substitution on e_j)
        L[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * L[k, j]
            L[i, j] = s / L[i, i]
    for i in range(n):
        s = 0.0
        for k in range(i, n):
            s += L[k, i] * L[k, i]
        out[i] = s
    return True


def warm_up() -> None:
    """Compile ``rls_cascade`` (or load it from the cache) by running it once on two samples."""
    m = 2
    R = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    x, Lam, eta = np.zeros(6), np.eye(6), np.zeros(6)
    rls_cascade(
        np.ones((m, 3)),
        np.ones((m, 3)),
        R,
        x,
        Lam,
        eta,
        x.copy(),
        Lam.copy(),
        eta.copy(),
        np.array([400.0, 400.0, 1.0, 0.1, 1e-3]),
        status_array(),
        work_arrays(),
        DPOSV,
        np.empty((2, m, 3)),
        np.empty((3, m), dtype=np.bool_),
    )
    inverse_diag(Lam, np.empty((6, 6)), np.empty(6))
