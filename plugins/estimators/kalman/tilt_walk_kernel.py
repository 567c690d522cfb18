"""The tilt walk's intensity learnt from the data (``kalman``'s ``bias_force_tilt_rw = "auto"``).

The tilt walk (``plugins.estimators.kalman.stage``) lets the bias move by q_θ per radian the tool tilts. How much a
sensor's non-contact force changes with the tilt is the sensor's, its tool's and its cable's: nothing on a
simulator whose model is the filter's, a tenth of a newton or more per √rad on a real sensor. It is
measured the way a geostatistician measures a variogram, on the samples the filter accepts after the force
stage has settled:

* the accepted samples are cut into windows, each closed once gravity's direction in the sensor has turned
  ``TILT_WINDOW`` from where the window began (rad);
* between two neighbouring windows the residual's means, m̄ = ȳ − Ā·â (â the weight identified by the time
  the pair is scored, Ā the window's mean R_SB), differ by d. For a bias that walks by q_θ per radian and
  q_t per second, windows of Δθ and Δt each, seen through white noise σ², per axis

      E[|d|²]/3 = ⅔·q_θ·Δθ + ⅔·q_t·Δt + σ²·(1/n₁ + 1/n₂)

  (the ⅔: the variance of the difference of two neighbouring means of a walk), with Δθ the angle between
  the windows' mean directions of gravity and Δt between their middles, q_t the filter's own walk over time
  (N²/s) and σ² the sensor's white noise per axis, itself estimated from the differences of consecutive
  accepted samples less than ``NOISE_MAX_TURN`` apart (E|Δm|² = 6σ²; unlike the filter's noise estimate, it
  does not absorb a model error that changes with the tilt);
* each pair gives a sample q_i = 1.5·(|d|²/(3·c) − σ²·(1/n₁ + 1/n₂) − ⅔·q_t·Δt)/Δθ, c = ``CHI2_3_MEDIAN``
  (|d|²/3 of a Gaussian d is σ²·χ²₃/3, whose median is c·σ²), and q_θ is the median of the last
  ``TILT_PAIRS`` samples, 0 until ``MIN_PAIRS`` have been scored, and never below 0.

A contact must not count. A window in which the force stage refused a sample, and the window after it, are
left out, and a pair is scored only once the window after it has closed clean too (a contact's first newtons
are accepted before the gate refuses its ramp). A light contact the gate never refuses still moves a
window's mean. Where it begins or ends within a window it steps the residual there, and the window's residuals
spread more than the white noise and the walk over time explain: that window is left out too (``_stepped``,
``STEP_EXCESS``), unless most recent windows spread so (a sensor whose noise is not white, or so quiet that the
tilt error's own change shows: the test then says nothing about contacts and stands down). A touch whose edges
both fall between windows, or one that rises over several, is left to the median, which keeps it out as long
as fewer than half the recent pairs touch one. The torque
stage's refusals do not count: the force stage never depends on the torque's. A re-identified bias or a
payload change starts the windows afresh (``restart_windows``): a step of the bias or of the weight is no
turn's. A drift of the bias faster than the filter's walk over time counts as tilt (the walk then follows it
while the tool turns).

``learn_tilt_walk`` works on the state array ``tw`` (``TW_SIZE`` float64, laid out below); the compiled
cascade calls it per sample, the numpy reference runs it as Python (``learn_tilt_walk.py_func``), so both
learn the same q_θ. Nothing is allocated.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

TILT_WINDOW = 0.3
"""rad (17°): how far gravity's direction turns within one window. The real logs' model error changes
smoothly with the tilt (their variogram grows as Δθ² below ~0.15 rad), so a shorter lag sees little of it."""
TILT_PAIRS = 31
"""q_θ is the median of this many pairs' samples, the last ones scored."""
MIN_PAIRS = 5
"""q_θ stays 0 until this many pairs have been scored (one pair's sample is a single noisy square)."""
CHI2_3_MEDIAN = 0.7887
"""The median of χ²₃/3: |d|²/3 of a Gaussian d of variance V per axis has its median at this times V."""
NOISE_DIFFERENCES = 1000
"""The white-noise estimate's memory, in differences of consecutive accepted samples."""
NOISE_MAX_TURN = 0.03
"""rad: consecutive samples further apart than this give no difference for the white noise (a model error
that changes with the tilt would count as noise: a stream of random poses has no such pairs)."""
NOISE_MIN_DIFFERENCES = 30
"""No pair is scored before the white noise rests on this many differences (a stream of static poses far
apart never tells its noise from its model error, and keeps q_θ at 0)."""
STEP_EXCESS = 0.5
"""A window whose residuals spread more than (1 + this)·σ² (their variance averaged over the axes; σ² plus the
walk over time's share) is left out, as a refused one is: a light contact under the gate began or ended in it.
Windows free of contact spread about σ², half of those a light touch begins or ends in spread more than 1.5 σ²;
docs/estimators.md ("The tilt walk") has the measurements behind the figure."""
STEP_MEMORY = 16
"""The step test's share of failed windows is a running mean over about this many windows (the first ones
counted alike)."""
STEP_STAND_DOWN = 0.75
"""At this share of failed windows or more the step test stands down (``_stepped``): frequent light touches fail
it in under half of the windows (the ones a touch begins or ends in), while a sensor whose noise is not white
fails it in nearly all of them, and there the test says nothing about contacts (docs/estimators.md)."""

TW_Q, TW_S2, TW_S2_N, TW_PAIRS, TW_RING_AT = 0, 1, 2, 3, 4
TW_OPEN, TW_N, TW_T0, TW_DIRTY, TW_HAS_LAST, TW_AFTER = 5, 6, 7, 8, 9, 10
TW_SY, TW_SA, TW_G0, TW_LAST, TW_LAST_G, TW_SG = 11, 14, 23, 26, 29, 32
TW_SM, TW_SM2, TW_STEP_RATE, TW_STEP_N = 35, 38, 39, 40
TW_WIN = 41
WIN_Y, WIN_A, WIN_G, WIN_N, WIN_T, WIN_DIRTY, WIN_KNOWN, WIN_SIZE = 0, 3, 12, 15, 16, 17, 18, 19
TW_RING = TW_WIN + 2 * WIN_SIZE
TW_SORT = TW_RING + TILT_PAIRS
TW_SIZE = TW_SORT + TILT_PAIRS
"""``tw``, by index: the estimate q_θ (N²/rad per axis), the white noise σ² and the differences it rests on,
the pairs scored so far, where the next pair's sample goes in the ring; the open window's flag, accepted
samples, start time (s), whether a sample was refused in it, whether its last sample is kept, whether the
window before it had a refusal; its sums of y (3) and R_SB (9, row by row), gravity's direction in S where
it began (3), its last residual (3), gravity's direction in S at its last sample (3) and its sum (3), the sum
of its residuals (3) and of their squares; the share of the recent windows whose spread failed the step test,
and how many it rests on (up to ``STEP_MEMORY``); the two
windows closed last, older first, each: mean y (3), mean R_SB (9), gravity's mean direction (3), samples,
middle time, dirty, known; the ring of the last ``TILT_PAIRS`` pairs' samples; scratch for their median."""


def new_state() -> np.ndarray:
    """A fresh ``tw``: no window open, no pair scored, q_θ 0."""
    return np.zeros(TW_SIZE)


def restore(tw: np.ndarray, values) -> float:
    """Set ``tw`` (in place) to a saved one (a warm start: its windows go on where they were; a pair across a
    pause counts the pause's time as the bias's walk, one sample of the median, and a clock that went back
    starts the windows afresh); returns q_θ. ValueError if ``values`` is not a ``tw``. A state saved by an older
    version lacks the step test's values (``TW_SM`` to ``TW_STEP_N``): they start at 0, and its open window
    is dropped (its residual sums are not there to test it).
    """
    values = np.asarray(values, dtype=float)
    if values.ndim == 1 and len(values) == TW_SIZE - (TW_WIN - TW_SM):  # the layout before TW_SM
        values = np.insert(values, TW_SM, np.zeros(TW_WIN - TW_SM))
        values[TW_OPEN] = 0.0
    if values.shape != tw.shape or not np.all(np.isfinite(values)):
        raise ValueError(f"walk must be {len(tw)} finite numbers (the tilt walk's state)")
    counts = values[[TW_Q, TW_S2, TW_S2_N, TW_PAIRS, TW_N]]
    if counts.min() < 0 or not 0 <= values[TW_RING_AT] < TILT_PAIRS:
        raise ValueError(f"walk: its estimate, noise and counts must be >= 0 and its ring index below {TILT_PAIRS}")
    tw[:] = values
    return float(tw[TW_Q])


@njit(cache=True, error_model="numpy")
def restart_windows(tw) -> None:
    """Drop the open window and the closed ones (the estimate stays): the bias or the weight stepped."""
    tw[TW_OPEN], tw[TW_AFTER] = 0.0, 0.0
    tw[TW_WIN + WIN_KNOWN], tw[TW_WIN + WIN_SIZE + WIN_KNOWN] = 0.0, 0.0


@njit(cache=True, error_model="numpy")
def _median(tw, n) -> float:
    """The median of the ring's first n samples (insertion into the scratch; n ≤ TILT_PAIRS, once a window)."""
    for i in range(n):
        v = tw[TW_RING + i]
        j = i
        while j > 0 and tw[TW_SORT + j - 1] > v:
            tw[TW_SORT + j] = tw[TW_SORT + j - 1]
            j -= 1
        tw[TW_SORT + j] = v
    mid = n // 2
    return tw[TW_SORT + mid] if n % 2 == 1 else 0.5 * (tw[TW_SORT + mid - 1] + tw[TW_SORT + mid])


@njit(cache=True, error_model="numpy")
def _stepped(tw, t, q_time) -> bool:
    """Whether the open window is left out for a step: its residuals spread more than white noise and the walk
    over time explain, their variance (averaged over the axes) above (1 + ``STEP_EXCESS``)·(σ² + q_t·T/6), T
    its duration (s), while fewer than ``STEP_STAND_DOWN`` of the recent windows did (``STEP_MEMORY``). A
    light contact the gate took in steps the residual within the window; a tilt error the window turns through
    moves it smoothly. A sensor whose noise is not white (filtered inside it: consecutive samples alike, so σ²
    from their differences is too small), or so quiet that the tilt error's own change within a window shows,
    fails the test in most windows: it then says nothing about contacts, and stands down until it passes
    again. Never before the white noise is known."""
    n = tw[TW_N]
    if n < 2.0 or tw[TW_S2_N] < NOISE_MIN_DIFFERENCES:
        return False
    spread = tw[TW_SM2]
    for i in range(3):
        spread -= tw[TW_SM + i] * tw[TW_SM + i] / n
    expected = tw[TW_S2] + q_time * (t - tw[TW_T0]) / 6.0
    failed = spread / (3.0 * (n - 1.0)) > (1.0 + STEP_EXCESS) * expected
    standing = tw[TW_STEP_RATE] < STEP_STAND_DOWN  # (the share before this window)
    tw[TW_STEP_N] = min(tw[TW_STEP_N] + 1.0, STEP_MEMORY)
    tw[TW_STEP_RATE] += ((1.0 if failed else 0.0) - tw[TW_STEP_RATE]) / tw[TW_STEP_N]
    return failed and standing


@njit(cache=True, error_model="numpy")
def _score(tw, a, q_time):
    """Score the pair of closed windows (older, newer): its sample, 1.5·(|d|²/(3c) − σ²(1/n₁ + 1/n₂) −
    ⅔·q_t·Δt)/Δθ, into the ring, and q_θ the ring's median. a: â (≥3,); q_time: the bias's walk over time,
    N²/s."""
    o, w = TW_WIN, TW_WIN + WIN_SIZE
    d2 = 0.0
    for i in range(3):
        di = tw[w + WIN_Y + i] - tw[o + WIN_Y + i]
        for j in range(3):
            di -= (tw[w + WIN_A + 3 * i + j] - tw[o + WIN_A + 3 * i + j]) * a[j]
        d2 += di * di
    u0, u1, u2 = tw[o + WIN_G], tw[o + WIN_G + 1], tw[o + WIN_G + 2]
    v0, v1, v2 = tw[w + WIN_G], tw[w + WIN_G + 1], tw[w + WIN_G + 2]
    c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
    turn = math.atan2(math.sqrt(c0 * c0 + c1 * c1 + c2 * c2), u0 * v0 + u1 * v1 + u2 * v2)
    x = (
        d2 / (3.0 * CHI2_3_MEDIAN)
        - tw[TW_S2] * (1.0 / tw[o + WIN_N] + 1.0 / tw[w + WIN_N])
        - 2.0 / 3.0 * q_time * abs(tw[w + WIN_T] - tw[o + WIN_T])
    )
    if not (math.isfinite(x) and turn > 0.0):
        return
    at = int(tw[TW_RING_AT])
    tw[TW_RING + at] = 1.5 * x / turn
    tw[TW_RING_AT] = (at + 1) % TILT_PAIRS
    tw[TW_PAIRS] += 1.0
    n = int(min(tw[TW_PAIRS], TILT_PAIRS))
    if n >= MIN_PAIRS:
        tw[TW_Q] = max(_median(tw, n), 0.0)


@njit(cache=True, error_model="numpy")
def learn_tilt_walk(tw, y, A, a, g_B, t, refused, q_time) -> float:
    """One sample into the estimate; returns q_θ, N²/rad per axis.

    Args:
        tw: (TW_SIZE,) the state, in place. y: (3,) the force the weight and bias explain, N (force_S less
        any inertial force). A: (3, 3) R_SB at the sample. a: (≥3,) the force stage's state after the
        sample, its first three the weight gravity_force_B, N. g_B: (3,) gravity's direction in B (unit).
        t: the sample's time, s. refused: the force stage refused the sample. q_time: the bias's walk over
        time, N²/s (the mean over the axes).
    Call it for the samples the force stage tested once both stages have settled."""
    s0 = A[0, 0] * g_B[0] + A[0, 1] * g_B[1] + A[0, 2] * g_B[2]
    s1 = A[1, 0] * g_B[0] + A[1, 1] * g_B[1] + A[1, 2] * g_B[2]
    s2 = A[2, 0] * g_B[0] + A[2, 1] * g_B[1] + A[2, 2] * g_B[2]
    if not (math.isfinite(s0) and math.isfinite(s1) and math.isfinite(s2) and math.isfinite(t)):
        return tw[TW_Q]
    if tw[TW_OPEN] != 0.0 and t < tw[TW_T0]:  # the clock went back (a warm start from another clock)
        restart_windows(tw)
    if tw[TW_OPEN] == 0.0:  # a new window begins here
        tw[TW_OPEN], tw[TW_N], tw[TW_T0], tw[TW_HAS_LAST] = 1.0, 0.0, t, 0.0
        for i in range(12):
            tw[TW_SY + i] = 0.0
        for i in range(3):
            tw[TW_SG + i] = 0.0
            tw[TW_SM + i] = 0.0
        tw[TW_SM2] = 0.0
        tw[TW_G0], tw[TW_G0 + 1], tw[TW_G0 + 2] = s0, s1, s2
    if refused:
        tw[TW_DIRTY], tw[TW_HAS_LAST] = 1.0, 0.0
    else:
        tw[TW_N] += 1.0
        tw[TW_SG] += s0
        tw[TW_SG + 1] += s1
        tw[TW_SG + 2] += s2
        dm2 = 0.0
        for i in range(3):
            tw[TW_SY + i] += y[i]
            m = y[i]
            for j in range(3):
                tw[TW_SA + 3 * i + j] += A[i, j]
                m -= A[i, j] * a[j]
            dm2 += (m - tw[TW_LAST + i]) ** 2
            tw[TW_LAST + i] = m
            tw[TW_SM + i] += m
            tw[TW_SM2] += m * m
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
    if this_clean:  # (the step test, and its share of failed windows, only where nothing else left it out: a
        this_clean = not _stepped(tw, t, q_time)  # refused contact would fail it too and stand it down)
    if older_clean and newer_clean and this_clean and tw[TW_S2_N] >= NOISE_MIN_DIFFERENCES:
        _score(tw, a, q_time)  # (the window after the pair closed clean: no contact's ramp in the pair)
    for i in range(WIN_SIZE):
        tw[o + i] = tw[w + i]
    inv = 1.0 / n if n > 0.0 else 0.0
    for i in range(12):
        tw[w + WIN_Y + i] = tw[TW_SY + i] * inv
    for i in range(3):
        tw[w + WIN_G + i] = tw[TW_SG + i] * inv
    tw[w + WIN_N], tw[w + WIN_T] = n, 0.5 * (tw[TW_T0] + t)
    tw[w + WIN_DIRTY] = 0.0 if this_clean else 1.0
    tw[w + WIN_KNOWN] = 1.0
    tw[TW_OPEN] = 0.0
    tw[TW_AFTER], tw[TW_DIRTY] = tw[TW_DIRTY], 0.0  # the window after one with a refusal is left out too
    return tw[TW_Q]
