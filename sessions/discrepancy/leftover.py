"""What the discrepancy workflow's final model leaves, channel by channel: how much, and where.

Each channel's final RMS is set against that channel's own noise (:func:`axis_noise`: the sample-to-sample
differences, which whatever changes slower than the sampling does not enter); a channel above
:func:`leftover_threshold` is a leftover, and :func:`where_left` says where it lives (in time, in
frequency, by orientation) so that a person can name the physics. ``docs/discrepancy.md`` ("What is left,
per axis") has the threshold's measured false-positive rate.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from hapticlab.core.parallel import column_median, thread_map
from hapticlab.sessions.discrepancy.quality import noise_colour, quantised_noise
from hapticlab.sessions.offline.metrics import rms


def axis_noise(
    residual: np.ndarray,
    steps: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    rate_hz: float | None = None,
) -> np.ndarray:
    """(6,) each channel's noise from sample-to-sample differences (MAD/√2, repeated rows skipped): what is
    left that changes slower than the sampling (an unmodelled effect) does not count in it.

    A channel read on a grid (``steps`` (6,): its step, NaN where none; ``predicted`` (m, 6): the model's reading
    on the same rows) gets :func:`~hapticlab.sessions.discrepancy.quality.quantised_noise` instead: a quiet
    sensor's differences are mostly zero there and their MAD falls far below what the rounding leaves. A channel
    whose noise is coloured (:func:`~hapticlab.sessions.discrepancy.quality.noise_colour` at ``rate_hz``, the
    rows' rate, Hz; None: never) takes its differences over the lag where it decorrelates: over neighbours a
    low-passed noise mostly cancels (0.63x at ρ = 0.6)."""
    d = np.diff(residual, axis=0)
    moved = np.any(d != 0, axis=1)
    d = d[moved]
    if len(d) < 5:
        d = residual - np.median(residual, axis=0)
    mad = 1.4826 * column_median(np.abs(d - column_median(d))) / math.sqrt(2)

    def coloured(c: int) -> None:  # a coloured channel's MAD over the lag where its noise decorrelates
        lag = noise_colour(d[:, c], rate_hz)[0] if steps is None or not np.isfinite(steps[c]) else 1
        if lag > 1:
            dk = residual[lag:, c] - residual[:-lag, c]
            mad[c] = 1.4826 * float(np.median(np.abs(dk - np.median(dk)))) / math.sqrt(2)

    thread_map(coloured, range(residual.shape[1]))
    if steps is not None and predicted is not None and moved.sum() >= 5:
        delta = np.diff(predicted, axis=0)[moved]
        for k in np.flatnonzero(np.isfinite(steps)):
            step = float(steps[k])
            level = predicted[:, k] - (residual[0, k] + predicted[0, k]) % step  # from a grid point
            mad[k] = quantised_noise(d[:, k], delta[:, k], step, level)
    return np.maximum(mad, np.maximum(1e-3 * rms(residual), 1e-9))


def effective_samples(residual: np.ndarray, rate_hz: float | None) -> int:
    """How many independent samples the ``residual`` (m, 6), rows at ``rate_hz``, is worth for the leftover
    test: m, or, when a
    channel's noise is coloured (:func:`~hapticlab.sessions.discrepancy.quality.noise_colour`, AR(1) coefficient
    ρ), m·(1 − ρ)/(1 + ρ) for the most coloured channel (a correlated noise's RMS scatters as that many white
    samples' would)."""
    m = len(residual)
    d = np.diff(residual, axis=0)
    rho = max(noise_colour(d[:, k], rate_hz)[1] for k in range(residual.shape[1])) if m > 1 else 0.0
    return max(1, int(m * (1.0 - rho) / (1.0 + rho)))


LEFTOVER_SIGMAS = 4.0
"""How many of its own standard errors a channel's final RMS over its noise must lie above 1 to be a
leftover (:func:`leftover_threshold`)."""
LEFTOVER_SE = 1.1
"""The standard error of a channel's RMS over its noise estimate is ``LEFTOVER_SE / √n`` on n clean samples
(the RMS and the MAD of the differences, a 37 %-efficient estimator, each carry their sampling error); set
from simulated clean recordings with ``bench/discrepancy_null.py`` (the spread it found and the
false-positive rate: ``docs/discrepancy.md``, "What is left, per axis")."""
LEFTOVER_FLOOR = 0.05
"""A leftover is at least 5 % over the noise, however long the recording (a real sensor's noise is not
quite white)."""


LEFTOVER_SEGMENTS = 10
""":func:`where_left` splits the kept samples into this many stretches of time."""


GRAVITY_BINS = ("+x", "-x", "+y", "-y", "+z", "-z")
"""The orientations :func:`where_left` tells apart: the axis of S closest to gravity, and its sign."""


def where_left(t: np.ndarray, residual: np.ndarray, noise: float, weight_S: np.ndarray | None = None) -> dict[str, Any]:
    """Where a channel's leftover lives: in time (the stretches whose RMS over ``noise`` exceeds the leftover
    threshold for their size), in frequency (the periodogram's peak, and the share of the residual's power
    within ±1 bin of it), in pose space (the orientations, by the axis of S gravity is closest to, where it
    exceeds the threshold) and how much (the RMS beyond the noise).

    Args:
        t: (m,) the kept samples' times, s (or rows); residual: (m,) that channel's final residual there;
        noise: the channel's own noise (:func:`axis_noise`); weight_S: (m, 3) the model's weight in S
        there, N (None: no pose-space split).
    """
    m = len(t)
    edges = np.linspace(0, m, LEFTOVER_SEGMENTS + 1).astype(int)
    stretches = []
    for a, b in itertools.pairwise(edges):
        if b - a < 2:
            continue
        ratio = float(rms(residual[a:b])) / noise
        if ratio > leftover_threshold(b - a):
            stretches.append({"t_start": float(t[a]), "t_end": float(t[b - 1]), "rms_over_noise": ratio})
    x = residual - residual.mean()
    dt = float(np.median(np.diff(t))) if m > 1 else 1.0
    spectrum = np.abs(np.fft.rfft(x * np.hanning(m))) ** 2
    freq = np.fft.rfftfreq(m, dt)
    k = int(np.argmax(spectrum[1:])) + 1 if m > 2 else 0
    excess = max(float(np.mean(x**2)) - noise**2, 0.0)
    share = float(spectrum[max(k - 1, 1) : k + 2].sum() / spectrum[1:].sum()) if spectrum[1:].sum() > 0 else 0.0
    orientations, tested = [], []
    if weight_S is not None and m:
        axis = np.argmax(np.abs(weight_S), axis=1)
        sign = np.sign(weight_S[np.arange(m), axis]) < 0
        for b, label in enumerate(GRAVITY_BINS):
            here = (axis == b // 2) & (sign == bool(b % 2))
            count = int(here.sum())
            if count < max(2, 0.02 * m):  # too few samples to say
                continue
            tested.append(label)
            ratio = float(rms(residual[here])) / noise
            if ratio > leftover_threshold(count):
                orientations.append({"gravity_S": label, "samples": count, "rms_over_noise": ratio})
    return {
        "stretches": stretches,
        "peak_hz": float(freq[k]) if dt > 0 else float("nan"),
        "peak_share": share,
        "orientations": orientations,
        "orientations_tested": tested,
        "excess_rms": math.sqrt(excess),
    }


def where_text(axis: str, where: dict[str, Any], time_base: str) -> str:
    unit = "s" if time_base == "seconds" else "rows"
    text = f"; {axis}: {where['excess_rms']:.3g} RMS beyond the noise"
    if where["peak_share"] >= 0.25 and time_base == "seconds":
        text += f", its spectrum peaking at {where['peak_hz']:.3g} Hz ({100 * where['peak_share']:.0f} % of the power)"
    stretches = where["stretches"]
    if stretches and len(stretches) < LEFTOVER_SEGMENTS:
        text += ", mostly in " + ", ".join(f"{s['t_start']:.4g}-{s['t_end']:.4g} {unit}" for s in stretches)
    elif stretches:
        text += ", all along"
    seen = [o["gravity_S"] for o in where["orientations"]]
    if seen:
        worst = max(where["orientations"], key=lambda o: o["rms_over_noise"])
        which = (
            "in every orientation"
            if len(seen) == len(where["orientations_tested"])
            else f"with gravity along {', '.join(seen)} in S"
        )
        text += f"; {which} (worst with gravity along {worst['gravity_S']}: {worst['rms_over_noise']:.2f}x)"
    return text


def leftover_threshold(n: int) -> float:
    """The ratio of a channel's final RMS to its own noise estimate above which the report flags what is left
    on it, for n samples: 1 + max(``LEFTOVER_FLOOR``, ``LEFTOVER_SIGMAS`` · ``LEFTOVER_SE`` / √n)."""
    return 1.0 + max(LEFTOVER_FLOOR, LEFTOVER_SIGMAS * LEFTOVER_SE / math.sqrt(max(n, 1)))
