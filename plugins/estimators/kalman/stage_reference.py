"""One kalman stage's filter in Python floats: the reference ``stage_kernel.py`` matches bit for bit.

``KalmanStage.run(method="fast")`` runs it; it transcribes the compiled ``filter6`` expression for
expression (numba compiles without fast-math, so both round alike).
"""

from __future__ import annotations


# per-sample arrays in capitals, one sample in lower case (dt = DT[k])
def filter6(x, P, Y, A, DT, TILT, ACTIVE, q, qt, r, rc, gate2, span, turn):  # noqa: N803
    """The stage filter for x = [a, b], C = [A, I3], in plain Python floats.

    P is the upper triangle of the symmetric 6×6 covariance, row by row
    (21 numbers). The arithmetic is the textbook one: P⁻ = P + Q; PCᵀ; S = C PCᵀ + R;
    e = y − C x⁻; S = L·diag(d)·Lᵀ; d² = eᵀ S⁻¹ e; if accepted,
    x = x⁻ + PCᵀ S⁻¹ e and P = P⁻ − PCᵀ S⁻¹ (PCᵀ)ᵀ, evaluated through
    U = PCᵀ L⁻ᵀ as x⁻ + U diag(d)⁻¹ L⁻¹ e and P⁻ − U diag(d)⁻¹ Uᵀ.
    """
    x0, x1, x2, x3, x4, x5 = x
    (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25, p33, p34, p35, p44, p45, p55) = P
    q0, q1, q2 = q
    qt0, qt1, qt2 = qt
    r0, r1, r2 = r
    rc0, rc1, rc2 = rc
    cross = rc0 != 0.0 or rc1 != 0.0 or rc2 != 0.0
    nan = float("nan")
    X, D, G, E, FAILED = [], [], [], [], []  # noqa: N806 (per-sample outputs in capitals, as the arguments)
    for k in range(len(Y)):
        tilt = TILT[k]
        if tilt != 0.0:  # the tilt walk (kernel.add_tilt_noise; turn: since the stage last tested a sample)
            after = turn + tilt
            if span > 0.0:
                s0, s1 = (turn / span) ** 2, (after / span) ** 2
                p33 += min(qt0 * after, r0 * s1) - min(qt0 * turn, r0 * s0)
                p44 += min(qt1 * after, r1 * s1) - min(qt1 * turn, r1 * s0)
                p55 += min(qt2 * after, r2 * s1) - min(qt2 * turn, r2 * s0)
            else:
                p33 += qt0 * tilt
                p44 += qt1 * tilt
                p55 += qt2 * tilt
            turn = after
        dt = DT[k]
        if dt != 0.0:
            p33 += q0 * dt
            p44 += q1 * dt
            p55 += q2 * dt
        if ACTIVE[k]:
            a00, a01, a02, a10, a11, a12, a20, a21, a22 = A[k]
            y0, y1, y2 = Y[k]
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
                s00 += rc1 * x2 * x2 + rc2 * x1 * x1
                s11 += rc0 * x2 * x2 + rc2 * x0 * x0
                s22 += rc0 * x1 * x1 + rc1 * x0 * x0
                s01 -= rc2 * x0 * x1
                s02 -= rc1 * x0 * x2
                s12 -= rc0 * x1 * x2
            e0 = y0 - (a00 * x0 + a01 * x1 + a02 * x2 + x3)
            e1 = y1 - (a10 * x0 + a11 * x1 + a12 * x2 + x4)
            e2 = y2 - (a20 * x0 + a21 * x1 + a22 * x2 + x5)
            # S = L·diag(d)·Lᵀ (LDLᵀ, L unit lower triangular): d² and the update
            # without forming S⁻¹, as three decorrelated scalar updates
            try:
                d0 = s00
                l10 = s01 / d0
                l20 = s02 / d0
                d1 = s11 - l10 * s01
                t = s12 - l20 * s01
                l21 = t / d1
                d2_ = s22 - l20 * s02 - l21 * t
                z1 = e1 - l10 * e0  # z = L⁻¹ e
                z2 = e2 - l20 * e0 - l21 * z1
                z0 = e0 / d0  # then D⁻¹ z
                z1 /= d1
                z2 /= d2_
            except ZeroDivisionError:
                d0 = 0.0
            if not (d0 > 0.0 and d1 > 0.0 and d2_ > 0.0):  # S not numerically positive definite: no update
                FAILED.append(k)
                G.append(False)
                E.append(nan)
            elif not (d2 := z0 * z0 * d0 + z1 * z1 * d1 + z2 * z2 * d2_) <= gate2:  # eᵀ S⁻¹ e; refused (NaN too)
                E.append(d2)
                G.append(True)
                turn = 0.0  # tested
            else:
                E.append(d2)
                G.append(False)
                turn = 0.0  # tested
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
        else:
            G.append(False)
            E.append(nan)
        X += (x0, x1, x2, x3, x4, x5)
        D += (p00, p11, p22, p33, p44, p55)
    P = [p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25, p33, p34, p35, p44, p45, p55]
    return X, D, G, E, [x0, x1, x2, x3, x4, x5], P, FAILED, turn
