"""The kalman cascade compiled: both stages of a block in one call (one function: its loop shares their state).

``kalman_cascade`` runs the estimator's ``_filter_block`` over m samples: each stage's step
(``stage_kernel``: ``stage_step``, with bias-rate states ``stage_step_rate``, with the mount estimated
``stage_step_mount``), the noise estimate (``noise_kernel``), the convergence rules (``identified_kernel``),
the contact wrench and the contact flag, and the torque bias's re-opening (``rules_kernel``). Its options
and state travel in the ``adapt`` array (``state_layout.py``). Nothing is allocated; outputs go to arrays
the caller owns (``Buffers``).

It compiles in seconds the first time, then loads from the ``cache=True`` files in ``__pycache__``;
``warm_up()`` does it before the first live tick.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from hapticlab.plugins.estimators.kalman.derivatives_kernel import inertial_before
from hapticlab.plugins.estimators.kalman.identified_kernel import add_information, constant_var_max, predicted_var
from hapticlab.plugins.estimators.kalman.noise import NOISE_FLOOR, NOISE_REFUSED_WEIGHT, NOISE_WINDOW, NOISE_WINDOW_S
from hapticlab.plugins.estimators.kalman.noise_kernel import _auto_bound2, adapt_noise
from hapticlab.plugins.estimators.kalman.rules_kernel import (
    judge_contact,
    reopen_bias,
    set_gravity_direction,
    tilt_step,
    torque_only_refusal,
)
from hapticlab.plugins.estimators.kalman.stage_kernel import (
    FAILED,
    GATED,
    UPDATED,
    add_tilt_noise,
    filter6,
    stage_step,
    stage_step_mount,
    stage_step_rate,
)
from hapticlab.plugins.estimators.kalman.state_layout import (
    ADAPT_AUTO_F,
    ADAPT_AUTO_T,
    ADAPT_CAP_F,
    ADAPT_CAP_T,
    ADAPT_COUNT_F,
    ADAPT_COUNT_T,
    ADAPT_FORCE_SEEN,
    ADAPT_GRAVITY_DIR,
    ADAPT_GRAVITY_KNOWN,
    ADAPT_IDENTIFIED,
    ADAPT_MOUNT,
    ADAPT_NOISE_F,
    ADAPT_NOISE_T,
    ADAPT_PRED_F,
    ADAPT_PRIOR_TB,
    ADAPT_REOPEN_ROW,
    ADAPT_SIZE,
    ADAPT_TILT_AUTO,
    ADAPT_TILT_SPAN,
    ADAPT_TILT_TORQUE,
    ADAPT_TORQUE_EARLY,
    ADAPT_TORQUE_SEEN,
    ADAPT_TURN_F,
    ADAPT_TURN_T,
    ADAPT_TW,
    ADAPT_WINDOW,
    CONVERGENCE_AT_POSE,
)
from hapticlab.plugins.estimators.kalman.tilt_walk_kernel import learn_tilt_walk


@njit(cache=True, error_model="numpy")
def kalman_cascade(
    t_ns,
    last_t_ns,
    y_f,
    force_S,
    torque_S,
    A_f,
    stale,
    status,
    p_BoEo_B,
    inertial_S,
    motion,
    known,
    usable,
    x_f,
    P_f,
    x_t,
    P_t,
    q_f,
    r_f,
    rc_f,
    q_t,
    r_t,
    rc_t,
    qr_f,
    qr_t,
    qt_f,
    qt_t,
    R_SE,
    limits,
    adapt,
    info_f,
    info_t,
    A_t,
    scratch,
    work,
    X_f,
    D_f,
    gated_f,
    failed_f,
    X_t,
    D_t,
    gated_t,
    failed_t,
    contact_force_S,
    contact_torque_S,
    contact,
    converged_force,
    converged_torque,
):
    """The ``kalman`` estimator's cascade over m samples (its ``_filter_block``), in order.

    Force stage y = y_f, C = [A_f, I3]; its flag: max diag P[:6] < bound_f²; the torque stage
    sees the samples the force stage accepted with its flag up, C = [−[force_S − b_f]ₓ, I3]
    (b_f after the sample); its flag: max diag P_cog · |gravity_force_B|² < bound_t² and
    max diag P_bias < bound_t². With ``adapt[ADAPT_IDENTIFIED]`` the flags are instead the
    identified rule's (``plugins.estimators.kalman.identified``: the constant's variance from the accepted samples'
    information, and the reading's predicted variance at the pose, both under the bound), or at
    ``CONVERGENCE_AT_POSE`` the predicted variance alone (the constant's information is still kept:
    it says when the stage has settled, and what the motion has identified). With
    ``adapt[ADAPT_NOISE_F]`` / ``adapt[ADAPT_NOISE_T]`` that stage's noise is re-estimated after each
    sample (``plugins.estimators.kalman.noise``), the torque stage's carried force noise following the force's. A
    failed update (S not positive definite) is predicted only and lowers the flag. The contact
    wrench at the states after each sample (paper eqs. 20–21). With ``adapt[ADAPT_REOPEN_S]`` a lasting
    torque-only refusal re-opens the torque bias after the sample that completes it
    (:func:`torque_only_refusal`, :func:`reopen_bias`).

    Args:
        t_ns: (m,) int64 sample times, ns. last_t_ns: (2,) int64 [1 if a sample came before, its t_ns].
        y_f: (m, 3) what gravity and bias explain, N. force_S: (m, 3) N. torque_S: (m, 3) N·m.
        A_f: (m, 3, 3) R_SB per sample; with the mount estimated (``ADAPT_MOUNT``) R_EB in, and R_SB through
        the mount as it is after each sample out (in place). stale: (m,) bool. status: (m,) int64 sensor
        status (0: good).
        p_BoEo_B: (m, 3) positions, m, or (0, 3) when the stream has none. inertial_S: (m, 3) the
        tool's inertial force, N (y_f = force_S − inertial_S; it acts at the centre of mass), or (0, 3).
        motion: (m, 9) [ω_E, α_E, a_B] per sample, or (0, 9): given, each sample's inertial force is computed
        here from the states before it (``derivatives_kernel.inertial_before``, ``known`` (2,) [mass, centre
        of mass] known from a warm start), written into inertial_S and y_f (out), as a block of one would.
        usable: (m,) bool out: the
        samples the filter may use (``AlignedSamples.usable``: the guard has already refused a
        non-finite wrench or R_EB), less those whose force update failed.
        x_f, P_f, x_t, P_t: the stages' (n,) and (n, n), in place: n = 6, or 9 with bias-rate states
        (``stage_step_rate``). q_*, r_*, rc_*: (3,) as ``stage_step`` (r_f, r_t, rc_t in place with the noise
        estimate); qr_f, qr_t: (3,) the bias rates' random-walk variance per second (unused with 6 states);
        qt_f, qt_t: (3,) the biases' random-walk variance per radian of tilt, added to both stages before each
        sample (:func:`tilt_step` on A_f, :func:`add_tilt_noise`).
        R_SE: (3, 3) the mount's rotation, in place when it is estimated (then x_f is [a, b, (ḃ), θ],
        9 or 12 states, and its flag waits for std(θ)·|gravity_force_B| under the bound as well); read only
        then and with ``motion``.
        limits: (3,) [gate2, bound_f², bound_t²]. adapt: (ADAPT_SIZE,) see ``ADAPT_SIZE``.
        info_f, info_t: (6, 6) the stages' information Λ (identified rule), in place.
        A_t: (3, 3), scratch: (9, 6) scratch (the Cholesky factor, the torque reading's variance, the
        stages' [a, b] before the sample); work: (15, 9) the rate and mount steps' scratch.
        Out, (m, 6): X_f, D_f, X_t, D_t ([a, b] and their diag P);
        (m,): gated_f, failed_f, gated_t, failed_t; contact_force_S, contact_torque_S (m, 3);
        contact, converged_force, converged_torque (m,).

    Returns:
        (failed force updates, failed torque updates, gated force samples, first row with the
        force flag up or −1, the same for torque): what the caller would otherwise count.
    """
    gate2, bound_f2, bound_t2 = limits[0], limits[1], limits[2]
    noise_f, noise_t = adapt[ADAPT_NOISE_F] != 0.0, adapt[ADAPT_NOISE_T] != 0.0
    identified = adapt[ADAPT_IDENTIFIED] != 0.0
    at_pose = adapt[ADAPT_IDENTIFIED] == CONVERGENCE_AT_POSE
    torque_early = adapt[ADAPT_TORQUE_EARLY] != 0.0
    noise = noise_f or noise_t
    pred_f, pred_t = adapt[ADAPT_PRED_F : ADAPT_PRED_F + 3], scratch[6, :3]
    before_f, before_t = scratch[7], scratch[8]
    previous = last_t_ns[1]
    n_failed_f, n_failed_t, n_gated_f, first_f, first_t = 0, 0, 0, -1, -1
    adapt[ADAPT_REOPEN_ROW] = -1.0
    positions = p_BoEo_B.shape[0] != 0
    inertia = inertial_S.shape[0] != 0
    inertia_here = motion.shape[0] != 0
    rate = x_t.shape[0] == 9
    activate_var = adapt[ADAPT_MOUNT]
    mount = activate_var > 0.0
    n_f = x_f.shape[0]
    learn_walk = adapt[ADAPT_TILT_AUTO] != 0.0
    tilt_walk = qt_f.any() or qt_t.any() or learn_walk
    q_time = (q_f[0] + q_f[1] + q_f[2]) / 3.0
    turn_f, turn_t = 0.0, 0.0
    for k in range(t_ns.shape[0]):
        usable[k] = not stale[k] and status[k] == 0
        if positions:
            usable[k] = (
                usable[k]
                and math.isfinite(p_BoEo_B[k, 0])
                and math.isfinite(p_BoEo_B[k, 1])
                and math.isfinite(p_BoEo_B[k, 2])
            )
        if k == 0 and last_t_ns[0] == 0:
            step_ns = 0
        else:
            step_ns = t_ns[k] - previous
        previous = t_ns[k]
        dt = max(step_ns, 0) * 1e-9
        if inertia_here:  # (A_t: scratch until the torque stage's own, below)
            inertial_before(
                adapt, known, x_f, x_t, R_SE, A_f[k], mount, motion[k], force_S[k], y_f[k], inertial_S[k], A_t
            )
        if adapt[ADAPT_AUTO_F] != 0.0:
            bound_f2 = _auto_bound2(r_f, adapt[ADAPT_CAP_F])
        if adapt[ADAPT_AUTO_T] != 0.0:
            bound_t2 = _auto_bound2(r_t, adapt[ADAPT_CAP_T])
        if tilt_walk:
            tilt = tilt_step(adapt, A_f[k])
            turn_f = add_tilt_noise(P_f, qt_f, r_f, adapt[ADAPT_TURN_F], tilt, adapt[ADAPT_TILT_SPAN])
            turn_t = add_tilt_noise(P_t, qt_t, r_t, adapt[ADAPT_TURN_T], tilt, adapt[ADAPT_TILT_SPAN])
        before_f[:] = x_f[:6]
        if mount:
            what, _ = stage_step_mount(
                x_f,
                P_f,
                R_SE,
                y_f[k, 0],
                y_f[k, 1],
                y_f[k, 2],
                A_f[k],
                dt,
                usable[k],
                q_f,
                qr_f,
                r_f,
                gate2,
                activate_var,
                work,
            )
            R = A_f[k]  # R_EB in; R_SB = R_SE R_EB through the mount as it is now out
            for j in range(3):
                c0, c1, c2 = R[0, j], R[1, j], R[2, j]
                for i in range(3):
                    R[i, j] = R_SE[i, 0] * c0 + R_SE[i, 1] * c1 + R_SE[i, 2] * c2
        elif rate:
            what, _ = stage_step_rate(
                x_f, P_f, y_f[k, 0], y_f[k, 1], y_f[k, 2], A_f[k], dt, usable[k], q_f, qr_f, r_f, rc_f, gate2, work
            )
        else:
            what, _ = stage_step(
                x_f, P_f, y_f[k, 0], y_f[k, 1], y_f[k, 2], A_f[k], dt, usable[k], q_f, r_f, rc_f, gate2
            )
        failed = what == FAILED
        gated_f[k], failed_f[k] = what == GATED, failed
        if tilt_walk:
            adapt[ADAPT_TURN_F] = 0.0 if what == UPDATED or what == GATED else turn_f
        if failed:
            usable[k] = False
            n_failed_f += 1
        n_gated_f += what == GATED
        if identified or noise:
            predicted_var(P_f, A_f[k], pred_f)
        if identified:
            if usable[k] and what != GATED:
                add_information(info_f, A_f[k], r_f)
            known_here = max(pred_f[0], pred_f[1], pred_f[2]) < bound_f2 and not failed
            settled = constant_var_max(info_f, scratch) < bound_f2 and known_here
            conv = known_here if at_pose else settled
        else:
            conv = max(P_f[0, 0], P_f[1, 1], P_f[2, 2], P_f[3, 3], P_f[4, 4], P_f[5, 5]) < bound_f2 and not failed
            settled = conv
        if mount:  # the force a mount error can cause: std(θ)·|gravity_force_B|
            w2 = x_f[0] * x_f[0] + x_f[1] * x_f[1] + x_f[2] * x_f[2]
            mount_known = max(P_f[n_f - 3, n_f - 3], P_f[n_f - 2, n_f - 2], P_f[n_f - 1, n_f - 1]) * w2 < bound_f2
            conv = conv and mount_known
            settled = settled and mount_known
        converged_force[k] = conv
        if conv and first_f < 0:
            first_f = k
        d0, d1, d2 = force_S[k, 0], force_S[k, 1], force_S[k, 2]  # about the measured force (torque_bias.py)
        A_t[0, 0], A_t[0, 1], A_t[0, 2] = -0.0, d2, -d1
        A_t[1, 0], A_t[1, 1], A_t[1, 2] = -d2, -0.0, d0
        A_t[2, 0], A_t[2, 1], A_t[2, 2] = d1, -d0, -0.0
        seen = usable[k] and what != GATED and (settled or torque_early)  # (torque_start; settled: gravity known)
        before_t[:] = x_t[:6]
        if rate:
            what_t, _ = stage_step_rate(
                x_t,
                P_t,
                torque_S[k, 0],
                torque_S[k, 1],
                torque_S[k, 2],
                A_t,
                dt,
                seen,
                q_t,
                qr_t,
                r_t,
                rc_t,
                gate2,
                work,
            )
        else:
            what_t, _ = stage_step(
                x_t, P_t, torque_S[k, 0], torque_S[k, 1], torque_S[k, 2], A_t, dt, seen, q_t, r_t, rc_t, gate2
            )
        gated_t[k], failed_t[k] = what_t == GATED, what_t == FAILED
        if tilt_walk:
            adapt[ADAPT_TURN_T] = 0.0 if what_t == UPDATED or what_t == GATED else turn_t
        n_failed_t += what_t == FAILED
        force_seen = seen and settled  # (the torque re-opening counts the force stage's settled samples only)
        seen = seen and what_t != FAILED
        weight2 = x_f[0] ** 2 + x_f[1] ** 2 + x_f[2] ** 2  # |gravity_force_B|², N²
        if identified or noise:
            predicted_var(P_t, A_t, pred_t)
        if identified:
            if seen and what_t != GATED:
                add_information(info_t, A_t, r_t)
            known_t = max(pred_t[0], pred_t[1], pred_t[2]) < bound_t2 and what_t != FAILED
            if at_pose:  # the flag at the pose; the centre of gravity's identification asked until it has settled
                converged_torque[k] = known_t
                settled_t = (
                    known_t
                    and adapt[ADAPT_TORQUE_SEEN] == 0.0
                    and constant_var_max(info_t, scratch) * weight2 < bound_t2
                )
            else:
                settled_t = known_t and constant_var_max(info_t, scratch) * weight2 < bound_t2
                converged_torque[k] = settled_t
        else:
            converged_torque[k] = (
                max(P_t[0, 0], P_t[1, 1], P_t[2, 2]) * weight2 < bound_t2
                and max(P_t[3, 3], P_t[4, 4], P_t[5, 5]) < bound_t2
                and what_t != FAILED
            )
            settled_t = converged_torque[k]
        if torque_early:  # (started early: its flag and its settling still wait for the force stage's)
            converged_torque[k] = converged_torque[k] and conv
            settled_t = settled_t and settled
        if settled_t:
            adapt[ADAPT_TORQUE_SEEN] = 1.0
        if converged_torque[k] and first_t < 0:
            first_t = k
        if noise:
            if (
                adapt[ADAPT_WINDOW] == 0.0 and dt > 0.0
            ):  # plugins.estimators.kalman.noise.window_samples, at the first step
                adapt[ADAPT_WINDOW] = max(NOISE_WINDOW, int(NOISE_WINDOW_S / dt))
            window = adapt[ADAPT_WINDOW] if adapt[ADAPT_WINDOW] != 0.0 else NOISE_WINDOW
            refused_weight = NOISE_REFUSED_WEIGHT if adapt[ADAPT_FORCE_SEEN] == 0.0 else 0.0
            if noise_f and usable[k]:
                adapt[ADAPT_COUNT_F] = adapt_noise(
                    r_f,
                    adapt[ADAPT_COUNT_F],
                    y_f[k],
                    A_f[k],
                    before_f,
                    pred_f,
                    refused_weight if what == GATED else 1.0,
                    window,
                    NOISE_FLOOR[0],
                )
            if noise_t and seen:  # its R carries the force noise through the centre of gravity: not its own
                c0, c1, c2 = x_t[0], x_t[1], x_t[2]
                pred_t[0] += rc_t[1] * c2 * c2 + rc_t[2] * c1 * c1
                pred_t[1] += rc_t[0] * c2 * c2 + rc_t[2] * c0 * c0
                pred_t[2] += rc_t[0] * c1 * c1 + rc_t[1] * c0 * c0
                adapt[ADAPT_COUNT_T] = adapt_noise(
                    r_t,
                    adapt[ADAPT_COUNT_T],
                    torque_S[k],
                    A_t,
                    before_t,
                    pred_t,
                    refused_weight if what_t == GATED else 1.0,
                    window,
                    NOISE_FLOOR[1],
                )
            if noise_f:
                rc_t[0], rc_t[1], rc_t[2] = r_f[0], r_f[1], r_f[2]
        if settled and adapt[ADAPT_FORCE_SEEN] == 0.0:
            adapt[ADAPT_FORCE_SEEN] = 1.0
            if adapt[ADAPT_GRAVITY_KNOWN] == 0.0:  # tilts from here on about the identified weight
                set_gravity_direction(adapt, x_f)
            if adapt[ADAPT_AUTO_F] != 0.0:  # an auto bound never grows past its value once settled
                adapt[ADAPT_CAP_F] = math.sqrt(_auto_bound2(r_f, math.inf))
            if adapt[ADAPT_AUTO_T] != 0.0:
                adapt[ADAPT_CAP_T] = math.sqrt(_auto_bound2(r_t, math.inf))
        for i in range(6):
            X_f[k, i], D_f[k, i], X_t[k, i], D_t[k, i] = x_f[i], P_f[i, i], x_t[i], P_t[i, i]
        A = A_f[k]
        g0 = A[0, 0] * x_f[0] + A[0, 1] * x_f[1] + A[0, 2] * x_f[2]
        g1 = A[1, 0] * x_f[0] + A[1, 1] * x_f[1] + A[1, 2] * x_f[2]
        g2 = A[2, 0] * x_f[0] + A[2, 1] * x_f[1] + A[2, 2] * x_f[2]
        contact_force_S[k, 0] = y_f[k, 0] - g0 - x_f[3]
        contact_force_S[k, 1] = y_f[k, 1] - g1 - x_f[4]
        contact_force_S[k, 2] = y_f[k, 2] - g2 - x_f[5]
        t0, t1, t2 = torque_S[k, 0], torque_S[k, 1], torque_S[k, 2]
        if inertia:  # the inertial force's torque about S, c × f_inertial
            i0, i1, i2 = inertial_S[k, 0], inertial_S[k, 1], inertial_S[k, 2]
            t0, t1, t2 = (
                t0 - (x_t[1] * i2 - x_t[2] * i1),
                t1 - (x_t[2] * i0 - x_t[0] * i2),
                t2 - (x_t[0] * i1 - x_t[1] * i0),
            )
        w0, w1, w2 = g0 + x_f[3], g1 + x_f[4], g2 + x_f[5]  # the force model: x_t's bias is about it (b')
        contact_torque_S[k, 0] = t0 - (x_t[1] * w2 - x_t[2] * w1) - x_t[3]
        contact_torque_S[k, 1] = t1 - (x_t[2] * w0 - x_t[0] * w2) - x_t[4]
        contact_torque_S[k, 2] = t2 - (x_t[0] * w1 - x_t[1] * w0) - x_t[5]
        contact[k] = judge_contact(adapt, gated_f[k] or gated_t[k], usable[k])
        if torque_only_refusal(adapt, what == GATED, force_seen, what_t, dt, contact_force_S[k], contact_torque_S[k]):
            reopen_bias(P_t, info_t, adapt[ADAPT_PRIOR_TB : ADAPT_PRIOR_TB + 3])  # (from the next sample on)
            adapt[ADAPT_REOPEN_ROW] = k
        if learn_walk and usable[k] and adapt[ADAPT_FORCE_SEEN] != 0.0:  # the tilt walk from the data
            q = learn_tilt_walk(
                adapt[ADAPT_TW:],
                y_f[k],
                A_f[k],
                x_f,
                adapt[ADAPT_GRAVITY_DIR : ADAPT_GRAVITY_DIR + 3],
                t_ns[k] * 1e-9,
                gated_f[k],
                q_time,
            )
            qt_f[0], qt_f[1], qt_f[2] = q, q, q
            if adapt[ADAPT_TILT_TORQUE] >= 0.0:
                q *= adapt[ADAPT_TILT_TORQUE]
                qt_t[0], qt_t[1], qt_t[2] = q, q, q
    return n_failed_f, n_failed_t, n_gated_f, first_f, first_t


class Buffers:
    """The per-sample outputs of ``filter6`` / ``kalman_cascade`` for blocks of up to ``capacity`` samples,
    allocated once (grown, never shrunk, when a longer block comes); ``view(m)`` gives the first m rows."""

    def __init__(self, capacity: int = 64):
        self.capacity = 0
        self.grow(capacity)

    def grow(self, capacity: int) -> None:
        self.capacity = capacity
        self.X_f, self.D_f, self.X_t, self.D_t = (np.empty((capacity, 6)) for _ in range(4))
        self.gated_f, self.failed_f, self.gated_t, self.failed_t = (
            np.empty(capacity, dtype=np.bool_) for _ in range(4)
        )
        self.d2 = np.empty(capacity)
        self.usable = np.empty(capacity, dtype=np.bool_)
        self.A_t = np.empty((3, 3))
        self.scratch = np.empty((9, 6))
        self.work = np.empty((15, 9))

    def ensure(self, m: int) -> None:
        if m > self.capacity:
            self.grow(max(m, 2 * self.capacity))


def warm_up() -> None:
    """Compile ``filter6`` and ``kalman_cascade`` (or load them from the cache) by running each once."""
    m = 2
    A = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()
    y = np.ones((m, 3))
    b = Buffers(m)
    v3 = np.full(3, 1e-4)
    filter6(
        np.zeros(6),
        np.eye(6),
        y,
        A,
        np.full(m, 1e-3),
        np.full(m, 1e-3),
        np.ones(m, dtype=np.bool_),
        v3,
        v3,
        v3,
        np.zeros(3),
        20.0,
        0.15,
        np.zeros(1),
        b.X_f,
        b.D_f,
        b.gated_f,
        b.d2,
        b.failed_f,
    )
    for p, n in ((np.zeros((0, 3)), 6), (y, 6), (np.zeros((0, 3)), 9)):  # without and with positions, rates
        adapt = np.zeros(ADAPT_SIZE)
        for option in (ADAPT_NOISE_F, ADAPT_NOISE_T, ADAPT_IDENTIFIED, ADAPT_AUTO_F, ADAPT_AUTO_T):
            adapt[option] = 1.0
        adapt[ADAPT_CAP_F] = adapt[ADAPT_CAP_T] = np.inf
        kalman_cascade(
            np.arange(m, dtype=np.int64),
            np.zeros(2, dtype=np.int64),
            y,
            y,
            y,
            A,
            np.zeros(m, dtype=np.bool_),
            np.zeros(m, dtype=np.int64),
            p,
            p,
            np.zeros((len(p), 9)),  # (with positions: the inertial force computed here)
            np.zeros(2),
            np.ones(m, dtype=np.bool_),
            np.zeros(n),
            np.eye(n),
            np.zeros(n),
            np.eye(n),
            v3,
            v3.copy(),
            np.zeros(3),
            v3,
            v3.copy(),
            v3.copy(),
            v3,
            v3,
            v3,
            v3,
            np.eye(3),
            np.array([20.0, 1e-4, 1e-6]),
            adapt,
            np.eye(6),
            np.eye(6),
            b.A_t,
            b.scratch,
            b.work,
            b.X_f,
            b.D_f,
            b.gated_f,
            b.failed_f,
            b.X_t,
            b.D_t,
            b.gated_t,
            b.failed_t,
            np.empty((m, 3)),
            np.empty((m, 3)),
            np.empty(m, dtype=np.bool_),
            np.empty(m, dtype=np.bool_),
            np.empty(m, dtype=np.bool_),
        )
