"""Algorithm 1 as printed, per sample, compiled: the ``rls`` estimator's default hot path.

The same rules as ``plugins.estimators.rls.covariance_form`` (``printed_update`` under ``run_gated``) and
``plugins.estimators.rls.algorithm1``, over both stages, sample by sample, in place. With C_k = [A_k, I3]
and R = r·I3 (Simon 2006, §3.3; the paper's eqs. 26–28)::

    K_k = P_{k−1} C_kᵀ (R + C_k P_{k−1} C_kᵀ)⁻¹
    x_k = x_{k−1} + K_k (y_k − C_k x_{k−1})
    P_k = (I − K_k C_k) P_{k−1}                  (not symmetrised: as printed)

force stage A_k = R_EB, y_k = force_S (x = [gravity_force_B, bias_force_S]); torque stage
A_k = −[force_S − bias_force_S]ₓ, y_k = torque_S (x = [cog_S, bias_torque_S]), active where the force
stage's flag is up after the sample. The products are taken in the reference's order (C P first, then
(C P) Cᵀ; P Cᵀ, then (P Cᵀ) S⁻¹; K C, then (I − K C) P), S⁻¹ by LU with partial pivoting as LAPACK's
``dgesv`` (numpy's ``inv``) does, so the rounding is the reference's up to the order BLAS sums a dot
product in: an ulp here and there, which the printed update carries on (its P loses ~8 of its 16 digits
in the directions a sample has seen; ``covariance_form``). tests/plugins/estimators/rls/test_kernel.py
states how close that keeps the kernel to ``algorithm1`` (its flags included).

A zero pivot in S or a non-finite x leaves the stage as it was (``failed``). Nothing is allocated: the
stages' arrays are updated in place, ``work`` holds the per-sample temporaries.

Compiled the first time, then loaded from the ``cache=True`` files; ``warm_up()`` does it.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numba.extending import get_cython_function_address

from hapticlab.plugins.estimators.rls.information_form_kernel import (
    STATUS,
    _fma,
    lapack8,
    torque_regressor,
    write_contact_wrench,
)

__all__ = ["DGESV", "STATUS", "printed_cascade", "status_array", "warm_up", "work_arrays"]

DGESV = get_cython_function_address("scipy.linalg.cython_lapack", "dgesv")
"""Address of LAPACK's dgesv in scipy's library: LU with partial pivoting, what numpy's ``inv`` calls (it gives
numpy's bits for S⁻¹)."""


def status_array() -> np.ndarray:
    """(12,) int32 ``status`` for ``printed_cascade``: ``STATUS``' first six (flags and counts), then dgesv's
    integer arguments (n, info, ipiv (3,), one spare)."""
    return np.zeros(12, dtype=np.int32)


def work_arrays() -> np.ndarray:
    """(6, 6, 6) float64 scratch for ``printed_cascade`` (C, C P, P Cᵀ; S, S⁻¹ and the torque stage's A_k;
    K and x_k; P_k)."""
    return np.zeros((6, 6, 6))


@njit(cache=True)
def _inverse3(S, S_inv, lapack, dgesv) -> bool:
    """S⁻¹ of a (3, 3) S given in Fortran order (its transpose in C order), into ``S_inv`` in Fortran order:
    LAPACK's dgesv against I (LU with partial pivoting), as numpy's ``inv``. S is overwritten by its factors.
    False on a zero pivot. ``lapack``: (6,) int32 scratch (the end of ``status``); ``dgesv``: ``DGESV`` (an
    argument, not the global: a compiled constant would outlive the process whose address it is, in the cache)."""
    for i in range(3):
        for j in range(3):
            S_inv[i, j] = 1.0 if i == j else 0.0
    lapack[0], lapack[1] = 3, 0  # n (= nrhs = lda = ldb), info
    address = lapack.ctypes.data
    lapack8(dgesv, address, address, S.ctypes.data, address, address + 8, S_inv.ctypes.data, address, address + 4)  # type: ignore[call-arg]  # an @intrinsic is called without its typingctx
    return lapack[1] == 0


@njit(cache=True)
def _row_times_x(A, i, x):
    """Row i of C x, C = [A, I3], summed as numpy's gemv sums a row of six (OpenBLAS on x86-64: four lanes
    added pairwise, the last two fused): ((c0 x0 + c2 x2) + (c1 x1 + c3 x3)) + (c4 x4 + c5 x5)."""
    p0, p1, p2 = A[i, 0] * x[0], A[i, 1] * x[1], A[i, 2] * x[2]
    c3, c4, c5 = 1.0 if i == 0 else 0.0, 1.0 if i == 1 else 0.0, 1.0 if i == 2 else 0.0
    return ((p0 + p2) + (p1 + c3 * x[3])) + _fma(c4, x[4], c5 * x[5])


@njit(cache=True)
def _stage(y0, y1, y2, A, x, P, K, r, threshold, epsilon, converged, work, lapack, dgesv):
    """One active sample of one stage (``run_gated`` over ``printed_update``), in place.

    Args:
        y0, y1, y2: the measurement y_k (units of y). A: (3, 3) A_k.
        x: (6,) x. P: (6, 6) P. K: (6, 3) the last gain (written when the sample is used). r: R = r·I3.
        threshold: contact threshold on ‖C_k x_{k−1} − y_k‖. epsilon: convergence threshold on ‖Δx‖₂.
        converged: the stage's flag before the sample. work: ``work_arrays()``. lapack, dgesv: see ``_inverse3``.

    Returns:
        (flag out, gated, converged after, failed), as ``information_form_kernel._stage``.
    """
    e0 = _row_times_x(A, 0, x) - y0  # C_k x − y_k
    e1 = _row_times_x(A, 1, x) - y1
    e2 = _row_times_x(A, 2, x) - y2
    if converged and not e0 * e0 + e1 * e1 + e2 * e2 < threshold * threshold:
        return True, True, converged, False
    C, CP, PCt, Kk, Pk = work[0], work[1], work[2], work[4], work[5]
    flat = work[3].reshape(36)
    S, S_inv = flat[:9].reshape((3, 3)), flat[9:18].reshape((3, 3))  # (contiguous, for dgesv)
    for i in range(3):  # C = [A, I3]
        for j in range(3):
            C[i, j] = A[i, j]
            C[i, 3 + j] = 1.0 if i == j else 0.0
    for i in range(3):  # C P (3, 6)
        for j in range(6):
            s = 0.0
            for k in range(6):
                s = _fma(C[i, k], P[k, j], s)
            CP[i, j] = s
    for i in range(3):  # S = R + (C P) Cᵀ (3, 3), stored transposed (Fortran order, for dgesv)
        for j in range(3):
            s = 0.0
            for k in range(6):
                s = _fma(CP[i, k], C[j, k], s)
            S[j, i] = (r if i == j else 0.0) + s
    for i in range(6):  # P Cᵀ (6, 3)
        for j in range(3):
            s = 0.0
            for k in range(6):
                s = _fma(P[i, k], C[j, k], s)
            PCt[i, j] = s
    if not _inverse3(S, S_inv, lapack, dgesv):
        return False, False, converged, True
    for i in range(6):  # K = (P Cᵀ) S⁻¹ (6, 3); S_inv holds S⁻¹ transposed (Fortran order)
        for j in range(3):
            s = 0.0
            for k in range(3):
                s = _fma(PCt[i, k], S_inv[j, k], s)
            Kk[i, j] = s
    xk = Kk[:, 3]
    for i in range(6):  # x_k = x + K (y − C x), K's row times the innovation summed as numpy's gemv sums it
        xk[i] = x[i] + _fma(Kk[i, 2], -e2, _fma(Kk[i, 0], -e0, Kk[i, 1] * -e1))
    step2 = 0.0
    for i in range(6):
        d = xk[i] - x[i]
        step2 += d * d
    if not step2 < math.inf:  # a non-finite x: the stage stays as it was
        return False, False, converged, True
    IKC = work[0]  # (C is no longer needed: I − K C, (6, 6))
    for i in range(6):
        for j in range(6):
            s = Kk[i, 0] * (A[0, j] if j < 3 else (1.0 if j == 3 else 0.0))
            s = _fma(Kk[i, 1], A[1, j] if j < 3 else (1.0 if j == 4 else 0.0), s)
            s = _fma(Kk[i, 2], A[2, j] if j < 3 else (1.0 if j == 5 else 0.0), s)
            IKC[i, j] = (1.0 if i == j else 0.0) - s
    for i in range(6):  # P_k = (I − K C) P
        for j in range(6):
            s = 0.0
            for k in range(6):
                s = _fma(IKC[i, k], P[k, j], s)
            Pk[i, j] = s
    for i in range(6):
        x[i] = xk[i]
        for j in range(3):
            K[i, j] = Kk[i, j]
        for j in range(6):
            P[i, j] = Pk[i, j]
    converged = step2 < epsilon * epsilon
    return converged, False, converged, False


@njit(cache=True)
def printed_cascade(
    force_S, torque_S, R_EB, x_f, P_f, K_f, x_t, P_t, K_t, settings, status, work, dgesv, wrench, flags
):
    """Algorithm 1 as printed over m samples, in order: both stages updated in place, one output row each.

    Args:
        force_S: (m, 3) raw force, N. torque_S: (m, 3) raw torque, N·m. R_EB: (m, 3, 3).
        x_f: (6,), P_f: (6, 6), K_f: (6, 3) the force stage (x = [gravity_force_B, bias_force_S], N).
        x_t, P_t, K_t: the torque stage (x = [cog_S (m), bias_torque_S (N·m)]).
        settings: (5,) float64: r of the force and of the torque stage (N², (N·m)²: R = r·I3), then
            ``SETTINGS``' thresholds and ε. status: ``status_array()``, ``STATUS``
            (flags in and out, counts incremented). work: ``work_arrays()``. dgesv: ``DGESV``.
        wrench: (2, m, 3) out: contact_force_S (N) and contact_torque_S (N·m) (paper eqs. 20–21).
        flags: (3, m) bool out: contact, converged_force, converged_torque.
    """
    r_f, r_t, th_f, th_t, eps = settings[0], settings[1], settings[2], settings[3], settings[4]
    contact_force_S, contact_torque_S = wrench[0], wrench[1]
    contact, converged_force, converged_torque = flags[0], flags[1], flags[2]
    lapack = status[6:]
    conv_f = status[0] != 0
    conv_t = status[1] != 0
    A_t = work[3].reshape(36)[18:27].reshape((3, 3))
    for k in range(force_S.shape[0]):
        f0, f1, f2 = force_S[k, 0], force_S[k, 1], force_S[k, 2]
        R = R_EB[k]
        out_f, gated_f, conv_f, failed = _stage(
            f0, f1, f2, R, x_f, P_f, K_f, r_f, th_f, eps, conv_f, work, lapack, dgesv
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
                P_t,
                K_t,
                r_t,
                th_t,
                eps,
                conv_t,
                work,
                lapack,
                dgesv,
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


def warm_up() -> None:
    """Compile ``printed_cascade`` (or load it from the cache) by running it once on two samples."""
    m = 2
    R = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    printed_cascade(
        np.ones((m, 3)),
        np.ones((m, 3)),
        R,
        np.zeros(6),
        1e6 * np.eye(6),
        np.zeros((6, 3)),
        np.zeros(6),
        1e6 * np.eye(6),
        np.zeros((6, 3)),
        np.array([2.5e-3, 2.5e-3, 1.0, 0.1, 1e-3]),
        status_array(),
        work_arrays(),
        DGESV,
        np.empty((2, m, 3)),
        np.empty((3, m), dtype=np.bool_),
    )
