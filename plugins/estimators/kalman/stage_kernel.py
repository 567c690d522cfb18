"""One stage of the drift Kalman filter per sample, compiled (its three models share the update loops, so one file).

The ``kalman`` estimator's hot path.

The filter of ``plugins.estimators.kalman.stage`` for x = [a, b] (6 states), C_k = [A_k, I3], its arithmetic
transcribed expression for expression from ``plugins.estimators.kalman.stage_reference.filter6`` (the reference in
Python floats), so the results are the same bits: numba compiles without fast-math, so
no product is fused into an FMA and no sum is reordered. Per sample k:

    P⁻ = P + Q(dt_k),  Q = diag(0, 0, 0, q·dt_k)           q: (3,) bias random-walk variance rate, units²/s
    S  = C P⁻ Cᵀ + R_k, R_k = diag(r) + [a]ₓ diag(rc) [a]ₓᵀ  r: (3,) noise variance, units²; rc: (3,) of
                                                             the vector A_k is built from (torque stage)
    e  = y_k − C x⁻,    d² = eᵀ S⁻¹ e   (S = L·diag(d)·Lᵀ)
    d² > gate2: refused (gated); else x = x⁻ + P⁻Cᵀ S⁻¹ e, P = P⁻ − P⁻Cᵀ S⁻¹ C P⁻

Arrays: x (6,) in place; P (6, 6) symmetric in place (the upper triangle is read, both
are written). Entry points: ``stage_step`` (one sample) and ``filter6`` (one stage over
m samples: ``KalmanStage.run(method="numba")``); for the other models of a stage
``stage_step_rate`` (bias-rate states, x = [a, b, ḃ], 9: the same update in loops over
the states after the rate's prediction) and ``stage_step_mount`` (the force stage with
the mount estimated, ``plugins.estimators.kalman.mount_stage.MountStage``'s error-state EKF). The whole cascade of
both stages is ``plugins.estimators.kalman.cascade_kernel``. Nothing is allocated; outputs go to arrays the
caller owns.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

PREDICTED, UPDATED, GATED, FAILED = 0, 1, 2, 3
"""What ``stage_step`` did with a sample: predicted only (inactive), updated, refused by the
gate, or the update could not be computed (S not numerically positive definite)."""


@njit(cache=True, error_model="numpy")
def _with_cross_noise(s00, s01, s02, s11, s12, s22, rc0, rc1, rc2, x0, x1, x2):
    """S + [a]ₓ diag(rc) [a]ₓᵀ at a = (x0, x1, x2), S given and returned by its upper triangle."""
    return (
        s00 + (rc1 * x2 * x2 + rc2 * x1 * x1),
        s01 - rc2 * x0 * x1,
        s02 - rc1 * x0 * x2,
        s11 + (rc0 * x2 * x2 + rc2 * x0 * x0),
        s12 - rc0 * x1 * x2,
        s22 + (rc0 * x1 * x1 + rc1 * x0 * x0),
    )


@njit(cache=True, error_model="numpy")
def _gate_ldl3(s00, s01, s02, s11, s12, s22, e0, e1, e2, gate2):
    """S = L·diag(d)·Lᵀ (L unit lower triangular) of the symmetric 3×3 S, z = D⁻¹ L⁻¹ e and the gate on
    d² = eᵀ S⁻¹ e: returns (what, d², l10, l20, l21, d0, d1, d2, z0, z1, z2), what ``FAILED`` (a d not
    positive or NaN: S not numerically positive definite; x/0 gives inf or NaN here, where the Python
    reference catches ZeroDivisionError; d² NaN), ``GATED`` (d² > gate2, NaN too) or ``UPDATED`` (the
    sample may update)."""
    d0 = s00
    l10 = s01 / d0
    l20 = s02 / d0
    d1 = s11 - l10 * s01
    t = s12 - l20 * s01
    l21 = t / d1
    d2 = s22 - l20 * s02 - l21 * t
    z1 = e1 - l10 * e0  # z = L⁻¹ e
    z2 = e2 - l20 * e0 - l21 * z1
    z0 = e0 / d0  # then D⁻¹ z
    z1 /= d1
    z2 /= d2
    if not (d0 > 0.0 and d1 > 0.0 and d2 > 0.0):  # S not numerically positive definite: no update
        return FAILED, math.nan, l10, l20, l21, d0, d1, d2, z0, z1, z2
    m2 = z0 * z0 * d0 + z1 * z1 * d1 + z2 * z2 * d2  # eᵀ S⁻¹ e
    if not m2 <= gate2:  # refused (NaN too)
        return GATED, m2, l10, l20, l21, d0, d1, d2, z0, z1, z2
    return UPDATED, m2, l10, l20, l21, d0, d1, d2, z0, z1, z2


@njit(cache=True, error_model="numpy")
def add_tilt_noise(P, qt, r, turn, tilt, span) -> float:
    """The bias's random walk over a tilt, in place (``plugins.estimators.kalman.stage``'s "tilt walk" and its span);
    returns the stage's turn after it, turn + tilt.

    Per axis P's bias diagonal gains f(turn + tilt) − f(turn): f(Θ) = qt·Θ, or with a span
    min(qt·Θ, r·(Θ/span)²), Θ the turn since the stage last tested a sample (took it in or refused it). Over
    tested samples that is each sample's own capped walk; over samples it did not test (a sensor status, a
    stale pose) it adds up to the capped walk of the whole turn, however finely the turn was sampled.
    P: (n, n), the bias at rows 3..5. qt: (3,) variance per radian, units²/rad. r: (3,) the stage's noise
    variance per sample, units². turn: rad, the stage's turn so far (0 after a sample it tested). tilt: the
    angle gravity's direction turned in the sensor since the previous sample, rad (0: nothing to add).
    span: rad, the least turn the bias follows over (0: the plain walk). Added before the time step's
    prediction, which touches the bias block by F = I there (bias-rate states too: F's rate column adds
    nothing to a bias-only term), so the order is the model's."""
    if tilt == 0.0:
        return turn
    after = turn + tilt
    if span > 0.0:
        s0, s1 = (turn / span) ** 2, (after / span) ** 2
        P[3, 3] += min(qt[0] * after, r[0] * s1) - min(qt[0] * turn, r[0] * s0)
        P[4, 4] += min(qt[1] * after, r[1] * s1) - min(qt[1] * turn, r[1] * s0)
        P[5, 5] += min(qt[2] * after, r[2] * s1) - min(qt[2] * turn, r[2] * s0)
    else:
        P[3, 3] += qt[0] * tilt
        P[4, 4] += qt[1] * tilt
        P[5, 5] += qt[2] * tilt
    return after


@njit(cache=True, error_model="numpy")
def stage_step(x, P, y0, y1, y2, A, dt, active, q, r, rc, gate2):
    """One sample of one stage, in place.

    Args:
        x: (6,) [a, b]. P: (6, 6) covariance. y0, y1, y2: the measurement y_k.
        A: (3, 3) A_k. dt: time since the previous sample, s (>= 0). active: may update.
        q: (3,) bias random-walk variance per second. r: (3,) noise variance. rc: (3,) the
        cross noise's variance (zeros: none). gate2: the gate on d².

    Returns:
        (what, d2): ``PREDICTED``, ``UPDATED``, ``GATED`` or ``FAILED``, and d² (NaN
        when inactive or failed).
    """
    if dt != 0.0:
        P[3, 3] += q[0] * dt
        P[4, 4] += q[1] * dt
        P[5, 5] += q[2] * dt
    if not active:
        return PREDICTED, math.nan
    x0, x1, x2, x3, x4, x5 = x[0], x[1], x[2], x[3], x[4], x[5]
    p00, p01, p02, p03, p04, p05 = P[0, 0], P[0, 1], P[0, 2], P[0, 3], P[0, 4], P[0, 5]
    p11, p12, p13, p14, p15 = P[1, 1], P[1, 2], P[1, 3], P[1, 4], P[1, 5]
    p22, p23, p24, p25 = P[2, 2], P[2, 3], P[2, 4], P[2, 5]
    p33, p34, p35 = P[3, 3], P[3, 4], P[3, 5]
    p44, p45 = P[4, 4], P[4, 5]
    p55 = P[5, 5]
    r0, r1, r2 = r[0], r[1], r[2]
    rc0, rc1, rc2 = rc[0], rc[1], rc[2]
    cross = rc0 != 0.0 or rc1 != 0.0 or rc2 != 0.0
    a00, a01, a02 = A[0, 0], A[0, 1], A[0, 2]
    a10, a11, a12 = A[1, 0], A[1, 1], A[1, 2]
    a20, a21, a22 = A[2, 0], A[2, 1], A[2, 2]
    # PCᵀ: column l is P[:, :3] · A[l] + P[:, 3 + l]
    c00 = p00 * a00 + p01 * a01 + p02 * a02 + p03
    c10 = p01 * a00 + p11 * a01 + p12 * a02 + p13
    c20 = p02 * a00 + p12 * a01 + p22 * a02 + p23
    c30 = p03 * a00 + p13 * a01 + p23 * a02 + p33
    c40 = p04 * a00 + p14 * a01 + p24 * a02 + p34
    c50 = p05 * a00 + p15 * a01 + p25 * a02 + p35
    c01 = p00 * a10 + p01 * a11 + p02 * a12 + p04
    c11 = p01 * a10 + p11 * a11 + p12 * a12 + p14
    c21 = p02 * a10 + p12 * a11 + p22 * a12 + p24
    c31 = p03 * a10 + p13 * a11 + p23 * a12 + p34
    c41 = p04 * a10 + p14 * a11 + p24 * a12 + p44
    c51 = p05 * a10 + p15 * a11 + p25 * a12 + p45
    c02 = p00 * a20 + p01 * a21 + p02 * a22 + p05
    c12 = p01 * a20 + p11 * a21 + p12 * a22 + p15
    c22 = p02 * a20 + p12 * a21 + p22 * a22 + p25
    c32 = p03 * a20 + p13 * a21 + p23 * a22 + p35
    c42 = p04 * a20 + p14 * a21 + p24 * a22 + p45
    c52 = p05 * a20 + p15 * a21 + p25 * a22 + p55
    # S = C PCᵀ + R
    s00 = a00 * c00 + a01 * c10 + a02 * c20 + c30 + r0
    s01 = a00 * c01 + a01 * c11 + a02 * c21 + c31
    s02 = a00 * c02 + a01 * c12 + a02 * c22 + c32
    s11 = a10 * c01 + a11 * c11 + a12 * c21 + c41 + r1
    s12 = a10 * c02 + a11 * c12 + a12 * c22 + c42
    s22 = a20 * c02 + a21 * c12 + a22 * c22 + c52 + r2
    if cross:  # [a]ₓ diag(rc) [a]ₓᵀ at the prior estimate of a
        s00, s01, s02, s11, s12, s22 = _with_cross_noise(s00, s01, s02, s11, s12, s22, rc0, rc1, rc2, x0, x1, x2)
    e0 = y0 - (a00 * x0 + a01 * x1 + a02 * x2 + x3)
    e1 = y1 - (a10 * x0 + a11 * x1 + a12 * x2 + x4)
    e2 = y2 - (a20 * x0 + a21 * x1 + a22 * x2 + x5)
    # S = L·diag(d)·Lᵀ: d² and the update without forming S⁻¹, as three decorrelated scalar updates
    what, d2, l10, l20, l21, d0, d1, d2_, z0, z1, z2 = _gate_ldl3(s00, s01, s02, s11, s12, s22, e0, e1, e2, gate2)
    if what != UPDATED:
        return what, d2
    # U = PCᵀ L⁻ᵀ (columns u0, u1, u2); x += U D⁻¹ L⁻¹ e; P -= U D⁻¹ Uᵀ
    u10 = c01 - l10 * c00
    u11 = c11 - l10 * c10
    u12 = c21 - l10 * c20
    u13 = c31 - l10 * c30
    u14 = c41 - l10 * c40
    u15 = c51 - l10 * c50
    u20 = c02 - l20 * c00 - l21 * u10
    u21 = c12 - l20 * c10 - l21 * u11
    u22 = c22 - l20 * c20 - l21 * u12
    u23 = c32 - l20 * c30 - l21 * u13
    u24 = c42 - l20 * c40 - l21 * u14
    u25 = c52 - l20 * c50 - l21 * u15
    x0 += c00 * z0 + u10 * z1 + u20 * z2
    x1 += c10 * z0 + u11 * z1 + u21 * z2
    x2 += c20 * z0 + u12 * z1 + u22 * z2
    x3 += c30 * z0 + u13 * z1 + u23 * z2
    x4 += c40 * z0 + u14 * z1 + u24 * z2
    x5 += c50 * z0 + u15 * z1 + u25 * z2
    g0 = c00 / d0
    g1 = u10 / d1
    g2 = u20 / d2_
    p00 -= g0 * c00 + g1 * u10 + g2 * u20
    p01 -= g0 * c10 + g1 * u11 + g2 * u21
    p02 -= g0 * c20 + g1 * u12 + g2 * u22
    p03 -= g0 * c30 + g1 * u13 + g2 * u23
    p04 -= g0 * c40 + g1 * u14 + g2 * u24
    p05 -= g0 * c50 + g1 * u15 + g2 * u25
    g0 = c10 / d0
    g1 = u11 / d1
    g2 = u21 / d2_
    p11 -= g0 * c10 + g1 * u11 + g2 * u21
    p12 -= g0 * c20 + g1 * u12 + g2 * u22
    p13 -= g0 * c30 + g1 * u13 + g2 * u23
    p14 -= g0 * c40 + g1 * u14 + g2 * u24
    p15 -= g0 * c50 + g1 * u15 + g2 * u25
    g0 = c20 / d0
    g1 = u12 / d1
    g2 = u22 / d2_
    p22 -= g0 * c20 + g1 * u12 + g2 * u22
    p23 -= g0 * c30 + g1 * u13 + g2 * u23
    p24 -= g0 * c40 + g1 * u14 + g2 * u24
    p25 -= g0 * c50 + g1 * u15 + g2 * u25
    g0 = c30 / d0
    g1 = u13 / d1
    g2 = u23 / d2_
    p33 -= g0 * c30 + g1 * u13 + g2 * u23
    p34 -= g0 * c40 + g1 * u14 + g2 * u24
    p35 -= g0 * c50 + g1 * u15 + g2 * u25
    g0 = c40 / d0
    g1 = u14 / d1
    g2 = u24 / d2_
    p44 -= g0 * c40 + g1 * u14 + g2 * u24
    p45 -= g0 * c50 + g1 * u15 + g2 * u25
    p55 -= c50 * c50 / d0 + u15 * u15 / d1 + u25 * u25 / d2_

    x[0], x[1], x[2], x[3], x[4], x[5] = x0, x1, x2, x3, x4, x5
    P[0, 0], P[0, 1], P[0, 2], P[0, 3], P[0, 4], P[0, 5] = p00, p01, p02, p03, p04, p05
    P[1, 1], P[1, 2], P[1, 3], P[1, 4], P[1, 5] = p11, p12, p13, p14, p15
    P[2, 2], P[2, 3], P[2, 4], P[2, 5] = p22, p23, p24, p25
    P[3, 3], P[3, 4], P[3, 5] = p33, p34, p35
    P[4, 4], P[4, 5] = p44, p45
    P[5, 5] = p55
    for i in range(6):
        for j in range(i):
            P[i, j] = P[j, i]
    return UPDATED, d2


@njit(cache=True, error_model="numpy")
def _predict(x, P, dt, q, q_rate, rate):
    """Predict a stage over dt, in place (``plugins.estimators.kalman.stage.KalmanStage.transition``; n states, any
    beyond the bias and its rate, a mount's θ, carried unchanged). Without rate states P's bias diagonal gains q·dt.
    With them b += ḃ·dt and P = F P Fᵀ + Q, F = [I 0 0; 0 I dt·I; 0 0 I] (F's rows, then its columns,
    added to P), Q = [0 0 0; 0 q·dt + q_rate·dt³/3  q_rate·dt²/2; 0 q_rate·dt²/2  q_rate·dt]."""
    if dt == 0.0:
        return
    if not rate:
        for i in range(3):
            P[3 + i, 3 + i] += q[i] * dt
        return
    n = x.shape[0]
    for i in range(3):
        x[3 + i] += x[6 + i] * dt
    for i in range(3, 6):  # F P: a bias row gains dt × its rate's row
        for c in range(n):
            P[i, c] += dt * P[i + 3, c]
    for i in range(3, 6):  # (F P) Fᵀ: a bias column gains dt × its rate's column
        for c in range(n):
            P[c, i] += dt * P[c, i + 3]
    for i in range(3):
        half = q_rate[i] * dt * dt / 2.0
        P[3 + i, 3 + i] += q[i] * dt + q_rate[i] * dt * dt * dt / 3.0
        P[3 + i, 6 + i] += half
        P[6 + i, 3 + i] += half
        P[6 + i, 6 + i] += q_rate[i] * dt


@njit(cache=True, error_model="numpy")
def _update(x, P, y0, y1, y2, r, rc, gate2, work):
    """The Kalman update of n states with the measurement matrix C (3, n) given as Cᵀ in ``work[:n, 6:9]``,
    in place: S = C P Cᵀ + R (R = diag(r) + [a]ₓ diag(rc) [a]ₓᵀ at the prior a = x[:3]), e = y − C x,
    S = L·diag(d)·Lᵀ, d² = eᵀ S⁻¹ e; gated beyond gate2, else x += P Cᵀ S⁻¹ e and P −= P Cᵀ S⁻¹ C P as
    three decorrelated scalar updates (``stage_step``'s, in loops). ``work[:n, 0:6]``: scratch (P Cᵀ, then
    U = P Cᵀ L⁻ᵀ). Returns (what, d²) as ``stage_step``."""
    n = x.shape[0]
    for c in range(n):  # P Cᵀ
        for l in range(3):
            acc = 0.0
            for j in range(n):
                acc += P[c, j] * work[j, 6 + l]
            work[c, l] = acc
    s00, s01, s02, s11, s12, s22 = r[0], 0.0, 0.0, r[1], 0.0, r[2]
    e0, e1, e2 = y0, y1, y2
    for j in range(n):
        s00 += work[j, 6] * work[j, 0]
        s01 += work[j, 6] * work[j, 1]
        s02 += work[j, 6] * work[j, 2]
        s11 += work[j, 7] * work[j, 1]
        s12 += work[j, 7] * work[j, 2]
        s22 += work[j, 8] * work[j, 2]
        e0 -= work[j, 6] * x[j]
        e1 -= work[j, 7] * x[j]
        e2 -= work[j, 8] * x[j]
    x0, x1, x2 = x[0], x[1], x[2]
    if rc[0] != 0.0 or rc[1] != 0.0 or rc[2] != 0.0:  # [a]ₓ diag(rc) [a]ₓᵀ at the prior estimate of a
        s00, s01, s02, s11, s12, s22 = _with_cross_noise(s00, s01, s02, s11, s12, s22, rc[0], rc[1], rc[2], x0, x1, x2)
    what, d2, l10, l20, l21, d0, d1, d2_, z0, z1, z2 = _gate_ldl3(s00, s01, s02, s11, s12, s22, e0, e1, e2, gate2)
    if what != UPDATED:
        return what, d2
    for c in range(n):  # U = P Cᵀ L⁻ᵀ in work[:, 3:6] (its first column is P Cᵀ's)
        work[c, 3] = work[c, 0]
        work[c, 4] = work[c, 1] - l10 * work[c, 0]
        work[c, 5] = work[c, 2] - l20 * work[c, 0] - l21 * work[c, 4]
    for c in range(n):
        x[c] += work[c, 3] * z0 + work[c, 4] * z1 + work[c, 5] * z2
    for i in range(n):  # P −= U D⁻¹ Uᵀ, symmetric
        g0, g1, g2 = work[i, 3] / d0, work[i, 4] / d1, work[i, 5] / d2_
        for j in range(i, n):
            P[i, j] -= g0 * work[j, 3] + g1 * work[j, 4] + g2 * work[j, 5]
            P[j, i] = P[i, j]
    return UPDATED, d2


@njit(cache=True, error_model="numpy")
def stage_step_rate(x, P, y0, y1, y2, A, dt, active, q, q_rate, r, rc, gate2, work):
    """``stage_step`` for x = [a, b, ḃ] (9 states: ``bias_rate``), in place; ``work`` (≥ 9, 9) scratch.

    :func:`_predict` with the rate, then :func:`_update` with C = [A, I3, 0]: the filterpy reference's
    filter (its Joseph form, its products in another order; tests hold them to 1e-9). Returns (what, d²)
    as ``stage_step``.
    """
    _predict(x, P, dt, q, q_rate, True)
    if not active:
        return PREDICTED, math.nan
    n = x.shape[0]
    for j in range(n):  # Cᵀ
        for l in range(3):
            work[j, 6 + l] = A[l, j] if j < 3 else (1.0 if j == 3 + l else 0.0)
    return _update(x, P, y0, y1, y2, r, rc, gate2, work)


@njit(cache=True, error_model="numpy")
def stage_step_mount(x, P, R_SE, y0, y1, y2, R_EB, dt, active, q, q_rate, r, gate2, activate_var, work):
    """The force stage with the mount rotation estimated (``plugins.estimators.kalman.mount_stage.MountStage``, an
    error-state EKF), one sample in place: x = [a, b, (ḃ), θ] (9 or 12 states), R_SE (3, 3) the nominal mount.

    :func:`_predict` (θ carried), then :func:`_update` with C = [R_SE R_EB, I3, (0), −R_SE [R_EB a]ₓ]
    (the θ columns zero while max diag P_a > ``activate_var``: the weight not yet known, θ waits); after
    an accepted update θ is folded into the mount, R_SE ← R_SE Exp(θ), θ ← 0 (Rodrigues, as
    ``plugins.estimators.kalman.mount_stage._exp_so3``). No cross noise (the force stage's). ``work`` (≥ n, 9) scratch.
    Returns (what, d²) as ``stage_step``.
    """
    n = x.shape[0]
    _predict(x, P, dt, q, q_rate, n == 12)
    if not active:
        return PREDICTED, math.nan
    v0 = R_EB[0, 0] * x[0] + R_EB[0, 1] * x[1] + R_EB[0, 2] * x[2]  # R_EB a: the weight in E
    v1 = R_EB[1, 0] * x[0] + R_EB[1, 1] * x[1] + R_EB[1, 2] * x[2]
    v2 = R_EB[2, 0] * x[0] + R_EB[2, 1] * x[1] + R_EB[2, 2] * x[2]
    learn = not max(P[0, 0], P[1, 1], P[2, 2]) > activate_var
    for l in range(3):
        for j in range(n):
            work[j, 6 + l] = 0.0
        for j in range(3):  # R_SE R_EB
            work[j, 6 + l] = R_SE[l, 0] * R_EB[0, j] + R_SE[l, 1] * R_EB[1, j] + R_SE[l, 2] * R_EB[2, j]
        work[3 + l, 6 + l] = 1.0
        if learn:  # −R_SE [v]ₓ, [v]ₓ = [[0, −v2, v1], [v2, 0, −v0], [−v1, v0, 0]]
            work[n - 3, 6 + l] = -(R_SE[l, 1] * v2 - R_SE[l, 2] * v1)
            work[n - 2, 6 + l] = -(-R_SE[l, 0] * v2 + R_SE[l, 2] * v0)
            work[n - 1, 6 + l] = -(R_SE[l, 0] * v1 - R_SE[l, 1] * v0)
    what, d2 = _update(x, P, y0, y1, y2, r, _NO_CROSS, gate2, work)
    if what == UPDATED:
        t0, t1, t2 = x[n - 3], x[n - 2], x[n - 1]
        angle = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if angle < 1e-8:
            c1, c2 = 1.0, 0.5
        else:
            c1, c2 = math.sin(angle) / angle, (1.0 - math.cos(angle)) / (angle * angle)
        # Exp(θ) = I + c1 K + c2 K², K = [θ]ₓ, K² = θ θᵀ − |θ|² I
        a2 = angle * angle
        e00, e01, e02 = 1.0 + c2 * (t0 * t0 - a2), -c1 * t2 + c2 * t0 * t1, c1 * t1 + c2 * t0 * t2
        e10, e11, e12 = c1 * t2 + c2 * t1 * t0, 1.0 + c2 * (t1 * t1 - a2), -c1 * t0 + c2 * t1 * t2
        e20, e21, e22 = -c1 * t1 + c2 * t2 * t0, c1 * t0 + c2 * t2 * t1, 1.0 + c2 * (t2 * t2 - a2)
        for i in range(3):
            m0 = R_SE[i, 0] * e00 + R_SE[i, 1] * e10 + R_SE[i, 2] * e20
            m1 = R_SE[i, 0] * e01 + R_SE[i, 1] * e11 + R_SE[i, 2] * e21
            m2 = R_SE[i, 0] * e02 + R_SE[i, 1] * e12 + R_SE[i, 2] * e22
            R_SE[i, 0], R_SE[i, 1], R_SE[i, 2] = m0, m1, m2
        x[n - 3], x[n - 2], x[n - 1] = 0.0, 0.0, 0.0
    return what, d2


_NO_CROSS = np.zeros(3)
"""The force stage's cross noise: none."""


@njit(cache=True, error_model="numpy")
def filter6(x, P, y, A, dt, tilt, active, q, qt, r, rc, gate2, span, turn, X, D, gated, d2, failed):
    """One stage over m samples, in order (``plugins.estimators.kalman.stage_reference.filter6``); x and P in place.

    Args:
        y: (m, 3) measurements. A: (m, 3, 3). dt: (m,) s. tilt: (m,) rad the tool tilted before each
        sample (:func:`add_tilt_noise`). active: (m,) bool. qt: (3,) the bias's random-walk variance per
        radian of tilt. span: rad, the tilt walk's; turn: (1,) the stage's turn since it last tested a sample,
        in and out (:func:`add_tilt_noise`). The rest as ``stage_step``. Out: X, D (m, 6) the state and diag P
        after each sample; gated, failed (m,) bool; d2 (m,) float.

    Returns:
        The number of failed samples.
    """
    n_failed = 0
    for k in range(y.shape[0]):
        after = add_tilt_noise(P, qt, r, turn[0], tilt[k], span)
        what, d2[k] = stage_step(x, P, y[k, 0], y[k, 1], y[k, 2], A[k], dt[k], active[k], q, r, rc, gate2)
        turn[0] = 0.0 if what == UPDATED or what == GATED else after
        gated[k] = what == GATED
        failed[k] = what == FAILED
        n_failed += what == FAILED
        for i in range(6):
            X[k, i] = x[i]
            D[k, i] = P[i, i]
    return n_failed
