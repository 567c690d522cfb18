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
  (a clip is a reading, not a contact: it must be flagged, not hidden).
"""

from __future__ import annotations

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


def pinned_rows(x: np.ndarray, others: np.ndarray | None = None) -> np.ndarray:
    """(n,) bool: the rows of ``x`` at its largest or smallest value in runs of at least :data:`PINNED_RUN`,
    while some of ``others`` (n, m: the other channels) change within the run (a log that repeats whole rows,
    as the LWR4 calibration logs do, repeats its extremes too: that is no clip)."""
    out = np.zeros(len(x), dtype=bool)
    finite = np.isfinite(x)
    if not finite.any():
        return out
    for extreme in (np.max(x[finite]), np.min(x[finite])):
        at = x == extreme
        edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
        for start, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            if end - start >= PINNED_RUN and (others is None or np.ptp(others[start:end], axis=0).max() > 0):
                out[start:end] = True
    return out


def data_quality(y: np.ndarray, t: np.ndarray, usable: np.ndarray, kept: np.ndarray, noise: np.ndarray) -> dict:
    """Per channel of ``y`` (n, 6: N and N·m) over the ``usable`` rows: its quantisation step and its share of
    ``noise`` (6,), and its saturation (rows pinned at an extreme: share, time span in ``t``'s units, share set
    aside by the gate, i.e. not in ``kept``). Returns ``{"channels": {axis: {...}}, "saturated": [axes]}``."""
    channels: dict[str, Any] = {}
    saturated = []
    rows = np.flatnonzero(usable)
    for k, axis in enumerate(AXES):
        x = y[rows, k]
        step = quantisation_step(x)
        pinned = pinned_rows(x, np.delete(y[rows], k, axis=1))
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
