"""The data's own quality, per channel, before any model: its quantisation step and whether it saturated.

A residual the model cannot explain is not always an effect of the world: the sensor may have clipped
(a channel pinned at the end of its range: the rows there read the range, not the force) or resolve its
noise in a few steps (an ADC step comparable to the noise). :func:`data_quality` reports both per channel
(fx..tz), from the readings alone:

* **step**: the channel's quantisation step, when its values lie on a grid (every value within 1 % of a step
  of a whole number of steps from the smallest), else None; beside it, the step's share of the channel's
  noise figure (a step over the noise makes the noise estimate a count of steps, not of noise);
* **saturation**: the rows whose value equals the channel's largest or smallest and sits in a run of at least
  :data:`PINNED_RUN` identical readings (a clipped sensor holds its limit; a noisy one never reads the same
  extreme twice in a row), their share, their time span, and the share of them the contact gate set aside
  (a clip is a reading, not a contact: it must be flagged, not hidden). On a quantised channel a quiet
  sensor holds its extreme level for a few rows at every turn of the load, so there a run is a clip only
  where the model's prediction goes beyond the level by more than a step and four noise figures.

:func:`quantised_noise` is the noise figure of a quantised channel: the sample-to-sample differences of a
quiet sensor whose step is comparable to its noise are mostly whole steps or zero, so their MAD collapses
(to 1/16-1/120 of the residual on a 16-bit-like sensor); it is taken instead from the differences' trimmed
variance, less what the rounding of a slow load cancels in them, plus the rounding's own variance where the
load sat (step²/12 when it swept the levels evenly).

:func:`noise_lag` is how many samples a channel's noise stays correlated over: the noise figures come from
sample-to-sample differences, which see only the part of a coloured (low-passed) noise that changes between
neighbours (an AR(1) noise of coefficient ρ: √(1 − ρ) of it); from differences over that lag they see it all.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")
PINNED_RUN = 3
"""Identical consecutive readings at a channel's extreme that make a clip (a 0.1 N noise repeats a 16-bit
reading three times in a row at its extreme with a chance of ~1e-9 per row)."""
MIN_PINNED = 5
"""The fewest pinned rows a channel needs to be flagged as saturated."""
GRID_TOLERANCE = 0.01
"""A value is on the grid within this share of a step."""
MAX_LEVELS_SHARE = 0.5
"""A channel is read as quantised only if its distinct values are at most this share of its rows."""


def quantisation_step(x: np.ndarray) -> float | None:
    """The step of the grid ``x`` (n,) lies on (same units), or None when it does not lie on one."""
    x = x[np.isfinite(x)]
    levels = np.unique(x)
    if len(levels) < 3 or len(levels) > MAX_LEVELS_SHARE * len(x):
        return None
    gaps = np.diff(levels)
    step = float(gaps.min())
    if step <= 0:
        return None
    k = (levels - levels[0]) / step
    return step if np.all(np.abs(k - np.round(k)) <= GRID_TOLERANCE) else None


CLIP_MARGIN_NOISE = 4.0
"""On a quantised channel a run at the extreme is a clip only where the prediction goes beyond the level by more
than a step plus this many noise figures (a quantised peak: within half a step and the noise)."""
DIFF_CUT = 5.0
"""A quantised channel's noise counts the sample-to-sample differences within this many robust spreads of their
median (a jump at a gap or a contact's edge does not count)."""
HARMONICS = 24
"""Terms of the quantisation error's Fourier series kept in :func:`quantised_noise` (the k-th is weighted 1/k²)."""


def quantised_noise(d: np.ndarray, delta: np.ndarray, step: float, level: np.ndarray) -> float:
    """The noise figure (same units) of a channel read on a grid of ``step``: the RMS a right model leaves
    there, √(mean E[(Q(x + n) − x)²]) over the rows' predicted readings x, n the analogue noise of σ.

    ``d`` (m,) are the residual's sample-to-sample differences, ``delta`` (m,) the prediction's over the same
    pairs, ``level`` (n,) the prediction on every row measured from a grid point. σ: s², the variance of the
    differences within :data:`DIFF_CUT` robust spreads (at least a step) of their median (their MAD alone reads a
    lattice of mostly 0 and ±step, not a bell: 17 % low at σ = 0.3 step); for a signal that moved by δ between
    two rows it is 2(σ² + step²/12 − C(δ, σ)), C the covariance of their rounding errors,
    (step²/2π²) Σₖ exp(−4π²k²σ²/step²) cos(2πkδ/step)/k² (a still load rounds both alike: C = step²/12 at
    σ = 0; a moving one or a noise over step/2 decorrelates them); σ solves s²/2 = σ² + step²/12 − mean C.
    Then E[(Q(x + n) − x)² | x] = σ² + step²/12 + Σₖ (−1)ᵏ exp(−2π²k²σ²/step²) cos(2πkx/step)
    (step²/π²k² + 4σ²) (x² at σ = 0): a load that sits near a level reads it exactly, one half-way between
    two reads half a step off, so the floor follows where this recording's load sat (step/√12 when it swept
    the levels evenly).
    """
    centre = float(np.median(d))
    spread = max(1.4826 * float(np.median(np.abs(d - centre))), step)
    inside = d[np.abs(d - centre) <= DIFF_CUT * spread]
    target = float(np.var(inside)) / 2.0 if len(inside) > 1 else 0.0
    k = np.arange(1, HARMONICS + 1)
    cosines = np.cos(2.0 * np.pi * np.outer(delta, k) / step).mean(axis=0) / k**2 * step * step / (2.0 * np.pi**2)

    def per_sample(sigma: float) -> float:  # σ² + step²/12 − mean C(δ, σ): increasing in σ
        return sigma * sigma + step * step / 12.0 - float(cosines @ np.exp(-4.0 * np.pi**2 * k**2 * sigma**2 / step**2))

    sigma = 0.0
    if per_sample(0.0) < target:
        lo, hi = 0.0, math.sqrt(target) + step
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if per_sample(mid) < target else (lo, mid)
        sigma = 0.5 * (lo + hi)
    at_levels = np.cos(2.0 * np.pi * np.outer(level, k) / step).mean(axis=0)
    smooth = (-1.0) ** k * np.exp(-2.0 * np.pi**2 * k**2 * sigma**2 / step**2)
    mean_square = (
        sigma * sigma
        + step * step / 12.0
        + float(at_levels @ (smooth * (step * step / (np.pi * k) ** 2 + 4 * sigma**2)))
    )
    return math.sqrt(max(mean_square, 0.0))


COLOUR_SIGMAS = 4.0
"""The noise is taken as coloured when its differences' lag-1 correlation is this many standard errors (1/√m) above
−0.5, white noise's (a 0.06 correlation between neighbouring samples at 7 500 rows)."""
MAX_NOISE_CORRELATION_S = 0.1
"""A noise correlated longer than this (s: the time constant −dt/ln ρ; a sensor's low-pass filter at 1.6 Hz or
above) is no sensor noise but a structure, and is not followed: a 10 Hz log's slow residual stays a leftover."""
NOISE_LAG_CORRELATION = 0.005
"""The noise's correlation at the lag :func:`noise_lag` chooses (an AR(1) model from the differences)."""
MAX_NOISE_LAG = 64
"""The longest lag, in samples, over which coloured noise is followed (and at most 0.26 s: a structure slower
than that is not noise)."""


def noise_colour(d: np.ndarray, rate_hz: float | None) -> tuple[int, float]:
    """The lag (samples) over which a channel's noise decorrelates, from its sample-to-sample differences ``d``
    (m,) sampled at ``rate_hz`` (None: ``t`` counts rows, whose order says nothing of time: white): 1 for white
    noise, whose differences correlate −0.5 with their neighbours. A noise correlated over a
    few samples (a sensor's low-pass filter) lifts that correlation to −(1 − ρ)/2 for an AR(1) noise of
    coefficient ρ; the lag is where ρᵏ falls under :data:`NOISE_LAG_CORRELATION` (0.5 %: the figure is then
    within 0.3 % of the noise's), and at least the first lag k from which the differences' correlations stay
    within 3 standard errors of 0 up to 2k (a noise that is not AR(1)); at most :data:`MAX_NOISE_LAG` and 0.26 s.
    A slow structure hardly enters the differences, so it does not lengthen the lag; a correlation longer than
    :data:`MAX_NOISE_CORRELATION_S` is taken for structure, not noise (white). Returns (lag, ρ), ρ = 0 for white
    noise."""
    m = len(d)
    if m < 50 or not rate_hz:
        return 1, 0.0
    x = d - d.mean()
    power = float(x @ x)
    if power <= 0:
        return 1, 0.0
    top = max(1, min(MAX_NOISE_LAG, m // 20, int(MAX_NOISE_LAG / 250.0 * rate_hz)))
    corr = np.array([float(x[j:] @ x[:-j]) / power for j in range(1, 2 * top + 1)])
    se = 1.0 / math.sqrt(m)
    if corr[0] + 0.5 <= COLOUR_SIGMAS * se:
        return 1, 0.0
    rho = min(1.0 + 2.0 * float(corr[0]), 0.999)
    if rho > 0 and -1.0 / (rate_hz * math.log(rho)) > MAX_NOISE_CORRELATION_S:
        return 1, 0.0
    lag = math.ceil(math.log(NOISE_LAG_CORRELATION) / math.log(rho)) if rho > 0 else 1
    for k in range(2, top + 1):
        if np.all(np.abs(corr[k - 1 : 2 * k]) < 3.0 * se):
            return int(min(max(lag, k), top)), rho
    return top, rho


def channel_steps(y: np.ndarray) -> np.ndarray:
    """(k,) each column's quantisation step (:func:`quantisation_step`) of ``y`` (n, k), NaN where none."""
    return np.array([s if (s := quantisation_step(y[:, j])) is not None else np.nan for j in range(y.shape[1])])


def pinned_rows(
    x: np.ndarray, others: np.ndarray | None = None, predicted: np.ndarray | None = None, margin: float = 0.0
) -> np.ndarray:
    """(n,) bool: the rows of ``x`` at its largest or smallest value in runs of at least :data:`PINNED_RUN`,
    while some of ``others`` (n, m: the other channels) change within the run (a log that repeats whole rows,
    as the LWR4 calibration logs do, repeats its extremes too: that is no clip) and, given ``predicted`` (n,),
    where it goes beyond that value by more than ``margin`` somewhere in the run (a quantised peak does not)."""
    out = np.zeros(len(x), dtype=bool)
    finite = np.isfinite(x)
    if not finite.any():
        return out
    for sign, extreme in ((1.0, np.max(x[finite])), (-1.0, np.min(x[finite]))):
        at = x == extreme
        edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
        for start, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            if end - start < PINNED_RUN or (others is not None and np.ptp(others[start:end], axis=0).max() == 0):
                continue
            if predicted is None or np.max(sign * (predicted[start:end] - extreme)) > margin:
                out[start:end] = True
    return out


def data_quality(
    y: np.ndarray,
    t: np.ndarray,
    usable: np.ndarray,
    kept: np.ndarray,
    noise: np.ndarray,
    predicted: np.ndarray | None = None,
) -> dict:
    """Per channel of ``y`` (n, 6: N and N·m) over the ``usable`` rows: its quantisation step and its share of
    ``noise`` (6,), and its saturation (rows pinned at an extreme: share, time span in ``t``'s units, share set
    aside by the gate, i.e. not in ``kept``; on a quantised channel only where ``predicted`` (n, 6), the model's
    reading, goes beyond the level by more than a step and :data:`CLIP_MARGIN_NOISE` noise figures).
    Returns ``{"channels": {axis: {...}}, "saturated": [axes]}``."""
    channels: dict[str, Any] = {}
    saturated = []
    rows = np.flatnonzero(usable)
    y_rows = y[rows]
    for k, axis in enumerate(AXES):
        x = np.ascontiguousarray(y_rows[:, k])
        step = quantisation_step(x)
        beyond = None if step is None or predicted is None else predicted[rows, k]
        margin = 0.0 if step is None else step + CLIP_MARGIN_NOISE * float(noise[k])
        pinned = pinned_rows(x, np.delete(y_rows, k, axis=1), beyond, margin)
        entry: dict[str, Any] = {
            "step": step,
            "step_over_noise": None if step is None or not noise[k] > 0 else step / float(noise[k]),
            "pinned_share": float(pinned.mean()) if len(x) else 0.0,
        }
        if pinned.sum() >= MIN_PINNED:
            where = rows[pinned]
            entry.update(
                pinned_at=float(x[pinned][0]),
                pinned_from=float(t[where[0]]),
                pinned_to=float(t[where[-1]]),
                pinned_set_aside_share=float(np.mean(~kept[where])),
            )
            saturated.append(axis)
        channels[axis] = entry
    return {"channels": channels, "saturated": saturated}


def quality_notes(quality: dict, unit: str) -> list[str]:
    """The notes a reader needs: each saturated channel, where and how much, and what the gate did with it."""
    notes = []
    for axis in quality["saturated"]:
        c = quality["channels"][axis]
        notes.append(
            f"{axis} is pinned at {c['pinned_at']:.6g} on {100 * c['pinned_share']:.1f} % of the rows "
            f"({c['pinned_from']:.6g}–{c['pinned_to']:.6g} {unit}): the sensor saturated there, and those rows read "
            f"its range, not the force ({100 * c['pinned_set_aside_share']:.0f} % of them set aside by the contact "
            f"gate); every figure over them is unreliable: cut them, or lower the load"
        )
    return notes
