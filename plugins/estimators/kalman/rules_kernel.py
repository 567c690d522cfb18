"""The rules the kalman cascade applies per sample, compiled: the contact judge, the tilt, the torque re-opening.

Each is an ``@njit`` function of the cascade's state array (``state_layout.py``); the compiled cascade
calls them, and the numpy reference runs the same functions as Python (``.py_func``), so both follow one
rule.
"""

from __future__ import annotations

import math

from numba import njit

from hapticlab.plugins.estimators.kalman.stage_kernel import GATED, UPDATED
from hapticlab.plugins.estimators.kalman.state_layout import (
    ADAPT_CONTACT_AFTER,
    ADAPT_GRAVITY_DIR,
    ADAPT_GRAVITY_KNOWN,
    ADAPT_HELD_OUT,
    ADAPT_REFUSED_RUN,
    ADAPT_REOPEN_LEVER,
    ADAPT_REOPEN_S,
    ADAPT_REOPENS,
    ADAPT_TILT,
    ADAPT_TQ_ONLY_N,
    ADAPT_TQ_ONLY_S,
    ADAPT_TQ_SUM_F,
    ADAPT_TQ_SUM_T,
)

TORQUE_REOPEN_MIN_SAMPLES = 10
"""A torque-only refusal re-opens the torque bias only once it is this many samples long as well as
``ADAPT_REOPEN_S`` (a few outliers of a slow stream are no drift)."""


@njit(cache=True, error_model="numpy")
def judge_contact(adapt, refused, tested) -> bool:
    """Whether a sample either stage refused is a contact: it is once it is the ``ADAPT_CONTACT_AFTER``-th
    refused sample in a row. The ones before are held out of the update all the same but not called a
    contact; a run that ends shorter (a lone outlier of a heavy-tailed noise, which a real sensor has:
    single samples at a Mahalanobis distance of 4.6–5.5 on the LWR4 logs) is counted in ``ADAPT_HELD_OUT``.
    A contact is seen that many samples late, its force is not: the contact wrench of a refused sample is
    its whole residual either way. A sample no stage tested (``tested`` False: stale, a sensor status, a
    failed update, no pose yet) neither continues nor ends the run. (The numpy reference runs this very
    function as Python: ``judge_contact.py_func``.)"""
    if not tested:
        return False
    run = adapt[ADAPT_REFUSED_RUN]
    if not refused:
        if 0.0 < run < adapt[ADAPT_CONTACT_AFTER]:  # a run that ended short: refused, never a contact
            adapt[ADAPT_HELD_OUT] += run
        adapt[ADAPT_REFUSED_RUN] = 0.0
        return False
    adapt[ADAPT_REFUSED_RUN] = run + 1.0
    return run + 1.0 >= adapt[ADAPT_CONTACT_AFTER]


@njit(cache=True, error_model="numpy")
def tilt_step(adapt, A) -> float:
    """The angle gravity's direction turned in the sensor since the previous sample, rad: between A ĝ and
    A_prev ĝ, ĝ the direction of gravity in B (``ADAPT_GRAVITY_DIR``; A = R_SB, or R_EB: the same angle),
    A_prev the previous sample's A (``ADAPT_TILT``), which A then becomes. atan2 of the cross and dot
    products: exact for small angles. 0 for the first sample; a non-finite A (a pose not known yet) neither
    tilts nor becomes the previous one. (The numpy reference runs this as ``tilt_step.py_func``.)"""
    d0, d1, d2 = adapt[ADAPT_GRAVITY_DIR], adapt[ADAPT_GRAVITY_DIR + 1], adapt[ADAPT_GRAVITY_DIR + 2]
    g0 = A[0, 0] * d0 + A[0, 1] * d1 + A[0, 2] * d2
    g1 = A[1, 0] * d0 + A[1, 1] * d1 + A[1, 2] * d2
    g2 = A[2, 0] * d0 + A[2, 1] * d1 + A[2, 2] * d2
    if not (math.isfinite(g0) and math.isfinite(g1) and math.isfinite(g2)):
        return 0.0
    known = math.isfinite(adapt[ADAPT_TILT])
    p = adapt[ADAPT_TILT : ADAPT_TILT + 9]
    p0 = p[0] * d0 + p[1] * d1 + p[2] * d2
    p1 = p[3] * d0 + p[4] * d1 + p[5] * d2
    p2 = p[6] * d0 + p[7] * d1 + p[8] * d2
    for i in range(3):
        for j in range(3):
            p[3 * i + j] = A[i, j]
    if not known:
        return 0.0
    c0, c1, c2 = p1 * g2 - p2 * g1, p2 * g0 - p0 * g2, p0 * g1 - p1 * g0
    return math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), p0 * g0 + p1 * g1 + p2 * g2)


@njit(cache=True, error_model="numpy")
def set_gravity_direction(adapt, a) -> None:
    """Measure tilts about the identified weight a (3,), N (its direction in B; a zero weight changes nothing):
    the base need not stand upright (a wall mount has gravity along B's x). ``tilt_step`` measures both
    samples' directions about the same ĝ, so the switch adds no spurious turn."""
    norm = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    if norm > 0.0 and math.isfinite(norm):
        for i in range(3):
            adapt[ADAPT_GRAVITY_DIR + i] = a[i] / norm
        adapt[ADAPT_GRAVITY_KNOWN] = 1.0


@njit(cache=True, error_model="numpy")
def torque_only_refusal(adapt, force_gated, force_seen, torque_what, dt, residual_force, residual_torque) -> bool:
    """Count a sample into the current torque-only refusal; True when the torque bias is to be re-opened.

    A drift of the torque bias (warm-up, a bias that a pose first visited shows to be off) makes the torque
    stage refuse samples the force stage accepts. So does a light contact (a force under the force stage's
    gate, at the tool's tip: a lever), and that must stay a contact: a contact force f acting within
    ``ADAPT_REOPEN_LEVER`` (L) of the sensor's origin makes a torque of at most L·|f|, so the bias is
    re-opened only when the run's mean torque residual is larger than that for its mean force residual,
    |Σ τ_res| > L·|Σ f_res|, once the run is ``ADAPT_REOPEN_S`` and ``TORQUE_REOPEN_MIN_SAMPLES`` long. A
    force the force stage refuses ends the run (a contact), and so does a sample the torque stage accepts.
    ``force_seen``: the force stage accepted the sample with its flag up (the torque stage saw it);
    ``torque_what``: what the torque stage did with it; the residuals: the sample's contact wrench (N, N·m).
    (The numpy reference runs this very function as Python: ``torque_only_refusal.py_func``.)"""
    if adapt[ADAPT_REOPEN_S] <= 0.0:
        return False
    if force_gated or (force_seen and torque_what == UPDATED):
        adapt[ADAPT_TQ_ONLY_S], adapt[ADAPT_TQ_ONLY_N] = 0.0, 0.0
        for i in range(3):
            adapt[ADAPT_TQ_SUM_F + i], adapt[ADAPT_TQ_SUM_T + i] = 0.0, 0.0
        return False
    if not (force_seen and torque_what == GATED):
        return False
    adapt[ADAPT_TQ_ONLY_S] += dt
    adapt[ADAPT_TQ_ONLY_N] += 1.0
    for i in range(3):
        adapt[ADAPT_TQ_SUM_F + i] += residual_force[i]
        adapt[ADAPT_TQ_SUM_T + i] += residual_torque[i]
    if adapt[ADAPT_TQ_ONLY_S] < adapt[ADAPT_REOPEN_S] or adapt[ADAPT_TQ_ONLY_N] < TORQUE_REOPEN_MIN_SAMPLES:
        return False
    f0, f1, f2 = adapt[ADAPT_TQ_SUM_F], adapt[ADAPT_TQ_SUM_F + 1], adapt[ADAPT_TQ_SUM_F + 2]
    t0, t1, t2 = adapt[ADAPT_TQ_SUM_T], adapt[ADAPT_TQ_SUM_T + 1], adapt[ADAPT_TQ_SUM_T + 2]
    lever = adapt[ADAPT_REOPEN_LEVER]
    if not t0 * t0 + t1 * t1 + t2 * t2 > lever * lever * (f0 * f0 + f1 * f1 + f2 * f2):
        return False  # a force within reach explains it: a light contact (the run goes on)
    adapt[ADAPT_TQ_ONLY_S], adapt[ADAPT_TQ_ONLY_N] = 0.0, 0.0
    for i in range(3):
        adapt[ADAPT_TQ_SUM_F + i], adapt[ADAPT_TQ_SUM_T + i] = 0.0, 0.0
    adapt[ADAPT_REOPENS] += 1.0
    return True


@njit(cache=True, error_model="numpy")
def reopen_bias(P, info, prior_var):
    """The stage's bias (states 3..5) unknown again, the rest as known (``KalmanEstimator._reopen_torque_bias``):
    P's bias rows and columns zeroed, its diagonal the prior variance ``prior_var`` (3,); the identified rule's
    Λ (6, 6) re-seeded from that P, which is block-diagonal: inv(P[:3, :3]) (cofactors), then 1/prior_var."""
    for i in range(3, 6):
        for j in range(P.shape[0]):
            P[i, j] = 0.0
            P[j, i] = 0.0
        P[i, i] = prior_var[i - 3]
    a, b, c = P[0, 0], P[0, 1], P[0, 2]
    d, e, f = P[1, 0], P[1, 1], P[1, 2]
    g, h, k = P[2, 0], P[2, 1], P[2, 2]
    c00, c01, c02 = e * k - f * h, c * h - b * k, b * f - c * e
    c10, c11, c12 = f * g - d * k, a * k - c * g, c * d - a * f
    c20, c21, c22 = d * h - e * g, b * g - a * h, a * e - b * d
    det = a * c00 + b * c10 + c * c20
    for i in range(6):
        for j in range(6):
            info[i, j] = 0.0
    info[0, 0], info[0, 1], info[0, 2] = c00 / det, c01 / det, c02 / det
    info[1, 0], info[1, 1], info[1, 2] = c10 / det, c11 / det, c12 / det
    info[2, 0], info[2, 1], info[2, 2] = c20 / det, c21 / det, c22 / det
    for i in range(3):
        info[3 + i, 3 + i] = 1.0 / prior_var[i]
