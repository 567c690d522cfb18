"""The tilt walk's intensity learnt from the data (``kalman``'s ``bias_force_tilt_rw = "auto"``).

The tilt walk (``core.kalman``) lets the bias move by q_θ per radian the tool tilts. How much a
sensor's non-contact force changes with the tilt is the sensor's, its tool's and its cable's: 0 on the simulator
(its model is the filter's), 0.2–0.45 N/√rad on the real logs. It is measured here the way a geostatistician
measures a variogram, on the samples the filter accepts after the force stage has settled:

* the accepted samples are cut into windows, each closed once gravity's direction in the sensor has turned
  ``TILT_WINDOW`` from where the window began (rad);
* between two neighbouring windows the residual's means, m̄ = ȳ − Ā·â (â the weight identified by the time
  the pair is scored, Ā the window's mean R_SB), differ by d; per axis

      E[|d|²]/3 = q_θ·Δθ + q_t·Δt + σ²·(1/n₁ + 1/n₂)

  with Δθ the angle between the windows' mean directions of gravity, Δt between their middles, q_t the
  filter's own walk over time (N²/s) and σ² the sensor's white noise per axis, itself estimated from the
  differences of consecutive accepted samples less than ``NOISE_MAX_TURN`` apart (E|Δm|² = 6σ²; unlike the
  filter's noise estimate, it does not absorb a model error that changes with the tilt);
* q_θ = max(0, Σ x / Σ Δθ), x = |d|²/3 − σ²·(1/n₁ + 1/n₂) − q_t·Δt, both sums forgetting with a memory of
  ``TILT_PAIRS`` pairs, ΣΔθ starting at ``PRIOR_TURN``.

A contact must not count: a window in which the force stage refused a sample, and the window after it, are
left out, and a pair is scored only once the window after it has closed clean too (a contact's first
newtons are accepted before the gate refuses its ramp). The torque stage's refusals do not count: the force
stage never depends on the torque's. Until a pair is scored q_θ is 0: no walk.

``learn_tilt_walk`` works on the state array ``tw`` (``TW_SIZE`` float64, laid out below); the compiled
cascade calls it per sample, the numpy reference runs it as Python (``learn_tilt_walk.py_func``), so both
learn the same q_θ to the bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TILT_WINDOW = 0.3
"""rad (17°): how far gravity's direction turns within one window. The real logs' model error changes
smoothly with the tilt (their variogram grows as Δθ² below ~0.15 rad), so a shorter lag sees little of it."""
TILT_PAIRS = 50
"""The estimate's memory, in window pairs (exponential forgetting)."""
PRIOR_TURN = 1.0
"""rad: q_θ starts at 0 as if measured over this much turn (ΣΔθ's start; Σx's is 0), so one pair cannot set
it alone (a pair's x is a single noisy square); it is forgotten as the pairs are."""
NOISE_DIFFERENCES = 1000
"""The white-noise estimate's memory, in differences of consecutive accepted samples."""
NOISE_MAX_TURN = 0.03
"""rad: consecutive samples further apart than this give no difference for the white noise (a model error
that changes with the tilt would count as noise: a stream of random poses has no such pairs)."""
NOISE_MIN_DIFFERENCES = 30
"""No pair is scored before the white noise rests on this many differences (a stream of static poses far
apart never tells its noise from its model error, and keeps q_θ at 0)."""

TW_Q, TW_NUM, TW_DEN, TW_S2, TW_S2_N = 0, 1, 2, 3, 4
TW_OPEN, TW_N, TW_T0, TW_DIRTY, TW_HAS_LAST, TW_PAIRS = 5, 6, 7, 8, 9, 10
TW_SY, TW_SA, TW_G0, TW_LAST, TW_AFTER, TW_LAST_G = 11, 14, 23, 26, 29, 30
TW_WIN = 33
WIN_Y, WIN_A, WIN_N, WIN_T, WIN_DIRTY, WIN_KNOWN, WIN_SIZE = 0, 3, 12, 13, 14, 15, 16
TW_SIZE = TW_WIN + 2 * WIN_SIZE
"""``tw``, by index: the estimate q_θ (N²/rad per axis), its forgetting sums Σx and ΣΔθ, the white noise σ²
and the differences it has seen; the open window's flag, accepted samples, start time (s), whether a sample
was refused in it, whether its last sample is kept; the pairs scored so far; its sums of y (3) and R_SB
(9, row by row), gravity's direction in S where it began (3), its last residual (3); whether the window
before it had a refusal; gravity's direction in S at its last sample (3); then the two windows closed
last, older first, each: mean y (3), mean R_SB (9), samples, middle time, dirty, known."""


def new_state() -> np.ndarray:
    """A fresh ``tw``: no window open, no pair scored, q_θ 0 (worth ``PRIOR_TURN``)."""
    tw = np.zeros(TW_SIZE)
    tw[TW_DEN] = PRIOR_TURN
    return tw


def restore(tw: np.ndarray, values) -> float:
    """Set ``tw`` (in place) to a saved one (a warm start: its windows go on where they were, and a pair that
    spans a pause counts the bias's walk over the pause's time); returns q_θ. ValueError if unusable."""
    values = np.asarray(values, dtype=float)
    if values.shape != tw.shape or not np.all(np.isfinite(values)) or values[TW_Q] < 0 or values[TW_DEN] <= 0:
        raise ValueError(f"must be {len(tw)} finite numbers (the tilt walk's state, q_θ >= 0 first)")
    tw[:] = values
    return float(tw[TW_Q])


@njit(cache=True, error_model="numpy")
def _score(tw, a, g_B, q_time):
    """Score the pair of closed windows (older, newer) into the estimate; a: â (≥3,), g_B: gravity's
    direction in B (3,), q_time: the bias's walk over time, N²/s."""
    o, w = TW_WIN, TW_WIN + WIN_SIZE
    d2, u0, u1, u2, v0, v1, v2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(3):
        di = tw[w + WIN_Y + i] - tw[o + WIN_Y + i]
        ui, vi = 0.0, 0.0
        for j in range(3):
            di -= (tw[w + WIN_A + 3 * i + j] - tw[o + WIN_A + 3 * i + j]) * a[j]
            ui += tw[o + WIN_A + 3 * i + j] * g_B[j]
            vi += tw[w + WIN_A + 3 * i + j] * g_B[j]
        d2 += di * di
        if i == 0:
            u0, v0 = ui, vi
        elif i == 1:
            u1, v1 = ui, vi
        else:
            u2, v2 = ui, vi
    c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    turn = math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), u0 * v0 + u1 * v1 + u2 * v2)
    x = d2 / 3.0 - tw[TW_S2] * (1.0 / tw[o + WIN_N] + 1.0 / tw[w + WIN_N]) \
        - q_time * abs(tw[w + WIN_T] - tw[o + WIN_T])
    if not (math.isfinite(x) and turn > 0.0):
        return
    keep = 1.0 - 1.0 / TILT_PAIRS
    tw[TW_NUM] = keep * tw[TW_NUM] + x
    tw[TW_DEN] = keep * tw[TW_DEN] + turn
    tw[TW_Q] = max(tw[TW_NUM] / tw[TW_DEN], 0.0)
    tw[TW_PAIRS] += 1.0


@njit(cache=True, error_model="numpy")
def learn_tilt_walk(tw, y, A, a, g_B, t, refused, q_time) -> float:
    """One sample into the estimate; returns q_θ, N²/rad per axis.

    Args:
        tw: (TW_SIZE,) the state, in place. y: (3,) the force the weight and bias explain, N (force_S less
        any inertial force). A: (3, 3) R_SB at the sample. a: (≥3,) the stage's state after the sample, its
        first three the weight gravity_force_B, N. g_B: (3,) gravity's direction in B (unit). t: the
        sample's time, s. refused: the force stage refused the sample. q_time: the bias's walk over time, N²/s
        (the mean over the axes).
    Call it only for samples the force stage tested, once it has settled."""
    s0 = A[0, 0] * g_B[0] + A[0, 1] * g_B[1] + A[0, 2] * g_B[2]
    s1 = A[1, 0] * g_B[0] + A[1, 1] * g_B[1] + A[1, 2] * g_B[2]
    s2 = A[2, 0] * g_B[0] + A[2, 1] * g_B[1] + A[2, 2] * g_B[2]
    if not (math.isfinite(s0) and math.isfinite(s1) and math.isfinite(s2) and math.isfinite(t)):
        return tw[TW_Q]
    if tw[TW_OPEN] == 0.0:  # a new window begins here
        tw[TW_OPEN], tw[TW_N], tw[TW_T0], tw[TW_HAS_LAST] = 1.0, 0.0, t, 0.0
        for i in range(12):
            tw[TW_SY + i] = 0.0
        tw[TW_G0], tw[TW_G0 + 1], tw[TW_G0 + 2] = s0, s1, s2
    if refused:
        tw[TW_DIRTY], tw[TW_HAS_LAST] = 1.0, 0.0
    else:
        tw[TW_N] += 1.0
        dm2 = 0.0
        for i in range(3):
            tw[TW_SY + i] += y[i]
            m = y[i]
            for j in range(3):
                tw[TW_SA + 3 * i + j] += A[i, j]
                m -= A[i, j] * a[j]
            dm2 += (m - tw[TW_LAST + i]) ** 2
            tw[TW_LAST + i] = m
        near = s0 * tw[TW_LAST_G] + s1 * tw[TW_LAST_G + 1] + s2 * tw[TW_LAST_G + 2] > math.cos(NOISE_MAX_TURN)
        tw[TW_LAST_G], tw[TW_LAST_G + 1], tw[TW_LAST_G + 2] = s0, s1, s2
        if tw[TW_HAS_LAST] != 0.0 and near and math.isfinite(dm2):
            tw[TW_S2_N] = min(tw[TW_S2_N] + 1.0, NOISE_DIFFERENCES)
            tw[TW_S2] += (dm2 / 6.0 - tw[TW_S2]) / tw[TW_S2_N]
        tw[TW_HAS_LAST] = 1.0
    if s0 * tw[TW_G0] + s1 * tw[TW_G0 + 1] + s2 * tw[TW_G0 + 2] > math.cos(TILT_WINDOW):
        return tw[TW_Q]
    # the window has turned far enough: it closes, and the newer closed one becomes the older
    o, w = TW_WIN, TW_WIN + WIN_SIZE
    older_clean = tw[o + WIN_KNOWN] != 0.0 and tw[o + WIN_DIRTY] == 0.0
    newer_clean = tw[w + WIN_KNOWN] != 0.0 and tw[w + WIN_DIRTY] == 0.0
    n = tw[TW_N]
    this_clean = tw[TW_DIRTY] == 0.0 and tw[TW_AFTER] == 0.0 and n > 0.0
    if older_clean and newer_clean and this_clean and tw[TW_S2_N] >= NOISE_MIN_DIFFERENCES:
        _score(tw, a, g_B, q_time)  # (the window after the pair closed clean: no contact's ramp in the pair)
    for i in range(WIN_SIZE):
        tw[o + i] = tw[w + i]
    for i in range(3):
        tw[w + WIN_Y + i] = tw[TW_SY + i] / n if n > 0.0 else 0.0
    for i in range(9):
        tw[w + WIN_A + i] = tw[TW_SA + i] / n if n > 0.0 else 0.0
    tw[w + WIN_N], tw[w + WIN_T] = n, 0.5 * (tw[TW_T0] + t)
    tw[w + WIN_DIRTY] = 0.0 if this_clean else 1.0
    tw[w + WIN_KNOWN] = 1.0
    tw[TW_OPEN] = 0.0
    tw[TW_AFTER], tw[TW_DIRTY] = tw[TW_DIRTY], 0.0  # the window after one with a refusal is left out too
    return tw[TW_Q]
