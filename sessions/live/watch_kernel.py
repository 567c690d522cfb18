"""The lag watch's per-block sums, compiled: how far the poses are out of step with the wrench.

For each sample k after the first one seen (``sessions/live/watch.py``,
``LagWatch``, holds the rules and the verdict; this is its arithmetic):

    g_k = R_SE · R_EB,k · gravity_force_B        (N, the predicted weight in S)
    r_k = force_S,k − g_k − bias_force_S          (N, the residual)
    ġ_k = (g_k − g_{k−1}) / (t_k − t_{k−1})       (N/s)

A sample is a contact when ‖r_k‖ > max_lag_s·‖ġ_k‖ + 3·noise (no lag up to
max_lag_s explains it); a sample is used when its step is positive, it is not a
contact, its residual is finite, it comes more than ``guard_ns`` after the last
contact (this block's included: its rising edge is no motion to learn from either)
and ‖ġ_k‖ ≤ max_turn_rad_s·‖gravity_force_B‖. At every step the sums forget,
S ← S·exp(−Δt/memory_s), and a used sample adds its terms, for

    S_rg = Σ r·ġ,   S_gg = Σ ġ·ġ,   S_rr = Σ r·r.

``sums`` (float64, 6): S_rg, S_gg, S_rr, then the last sample's g (3 entries);
``clock`` (int64, 3): the last sample's t_ns, the last contact's t_ns, flags
(bit 0: a last sample is known; bit 1: a contact is known). Both are updated in
place (tests/sessions/live/test_lag_watch.py: the lag of a turning tool, contacts,
blocks of 1 and 7 samples).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

HAS_LAST, HAS_CONTACT = 1, 2
"""Bits of ``clock[2]``."""


@njit(cache=True)
def lag_sums(
    t_ns,
    R_EB,
    force_S,
    R_SE,
    gravity_force_B,
    bias_force_S,
    noise,
    max_lag_s,
    guard_ns,
    max_turn_rad_s,
    memory_s,
    sums,
    clock,
):
    """Update ``sums`` and ``clock`` (see the module) with one block of n samples, in place.

    Args:
        t_ns: (n,) int64 sample times, ns. R_EB: (n, 3, 3). force_S: (n, 3) N.
        R_SE: (3, 3) the sensor's mount (identity when none). gravity_force_B, bias_force_S: (3,) N.
        noise: the sensor's force noise, N. max_lag_s, memory_s: s. guard_ns: ns. max_turn_rad_s: rad/s.
    """
    n = len(t_ns)
    g_norm = math.sqrt(gravity_force_B[0] ** 2 + gravity_force_B[1] ** 2 + gravity_force_B[2] ** 2)
    g = np.empty((n, 3))
    r = np.empty((n, 3))
    for k in range(n):
        for i in range(3):
            s = 0.0
            for j in range(3):
                R_SB_ij = R_SE[i, 0] * R_EB[k, 0, j] + R_SE[i, 1] * R_EB[k, 1, j] + R_SE[i, 2] * R_EB[k, 2, j]
                s += R_SB_ij * gravity_force_B[j]
            g[k, i] = s
            r[k, i] = force_S[k, i] - s - bias_force_S[i]
    has_last = (clock[2] & HAS_LAST) != 0
    first = 0 if has_last else 1  # the first sample ever seen only starts the differences
    if n == 0:
        return
    # pass 1: contacts (the newest one guards the whole block, as it guards what follows)
    g_dot = np.zeros((n, 3))
    contact = np.zeros(n, dtype=np.bool_)
    for k in range(first, n):
        tp = clock[0] if k == 0 else t_ns[k - 1]
        dt = (t_ns[k] - tp) * 1e-9
        step = dt if dt > 0 else 1.0
        gd2 = 0.0
        r2 = 0.0
        for i in range(3):
            gp = sums[3 + i] if k == 0 else g[k - 1, i]
            g_dot[k, i] = (g[k, i] - gp) / step
            gd2 += g_dot[k, i] ** 2
            r2 += r[k, i] ** 2
        if math.sqrt(r2) > max_lag_s * math.sqrt(gd2) + 3.0 * noise:  # False for a NaN residual
            contact[k] = True
            clock[1] = t_ns[k]
            clock[2] |= HAS_CONTACT
    # pass 2: the sums over the samples used, each step forgetting exp(−Δt/memory_s) (so the sums do not
    # depend on how the stream is cut into blocks)
    S_rg, S_gg, S_rr = sums[0], sums[1], sums[2]
    for k in range(first, n):
        tp = clock[0] if k == 0 else t_ns[k - 1]
        if t_ns[k] > tp:
            decay = math.exp(-((t_ns[k] - tp) * 1e-9) / memory_s)
            S_rg, S_gg, S_rr = S_rg * decay, S_gg * decay, S_rr * decay
        if t_ns[k] <= tp or contact[k]:
            continue
        if (clock[2] & HAS_CONTACT) != 0 and t_ns[k] - clock[1] <= guard_ns:
            continue
        finite = True
        gd2 = 0.0
        for i in range(3):
            finite = finite and math.isfinite(r[k, i])
            gd2 += g_dot[k, i] ** 2
        if not finite or not math.sqrt(gd2) <= max_turn_rad_s * g_norm:  # a NaN ġ (a NaN weight) too
            continue
        for i in range(3):
            S_rg += r[k, i] * g_dot[k, i]
            S_gg += g_dot[k, i] * g_dot[k, i]
            S_rr += r[k, i] * r[k, i]
    sums[0], sums[1], sums[2] = S_rg, S_gg, S_rr
    for i in range(3):
        sums[3 + i] = g[n - 1, i]
    clock[0] = t_ns[n - 1]
    clock[2] |= HAS_LAST


def warm_up() -> None:
    """Compile (or load from the cache) ``lag_sums`` before the first live tick."""
    eye = np.eye(3)
    lag_sums(
        np.array([0, 1_000_000], dtype=np.int64),
        np.stack([eye, eye]),
        np.zeros((2, 3)),
        eye,
        np.array([0.0, 0.0, -3.0]),
        np.zeros(3),
        0.12,
        0.5,
        500_000_000,
        10.0,
        0.25,
        np.zeros(6),
        np.zeros(3, dtype=np.int64),
    )
