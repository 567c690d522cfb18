"""The hand on an emulated master's handle: a scripted path or a recorded one, as a function of time.

A :data:`HandleMotion` maps the time since the path started (s) to the handle's position (m) and
velocity (m/s) in the device frame D. ``hapticlab emulate master --path`` takes one of ``PATHS``
or a CSV file; the bench's paced loop takes the same scripted paths.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hapticlab.core.host.options import choice, number

PATHS = ("circle", "figure8", "hold", "press")

HandleMotion = Callable[[float], tuple[np.ndarray, np.ndarray]]
"""t (s since start) → (p_DoHo_D m, v_DHo_D m/s)."""


def scripted_motion(
    kind: str = "circle",
    radius: float = 0.03,
    period: float = 8.0,
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> HandleMotion:
    """A handle moving about ``center`` (m), one lap per ``period`` s: ``circle`` or ``figure8`` (a lemniscate
    of Gerono, ``radius`` wide each way) in D's x-y plane, ``hold`` (still at ``center``), or ``press``
    (down along D's −z by up to ``radius`` and back, a raised cosine: a hand probing tissue by teleoperation)."""
    choice("path", kind, PATHS, hint=" (or a CSV file)")
    number("radius", radius, minimum=0, hint=" m")
    number("period", period, above=0, hint=" s")
    c = np.asarray(center, dtype=float)
    w = 2 * math.pi / period

    def motion(t: float) -> tuple[np.ndarray, np.ndarray]:
        a = w * t
        if kind == "circle":
            p = [radius * math.cos(a), radius * math.sin(a), 0.0]
            v = [-radius * w * math.sin(a), radius * w * math.cos(a), 0.0]
        elif kind == "press":
            p = [0.0, 0.0, -0.5 * radius * (1.0 - math.cos(a))]
            v = [0.0, 0.0, -0.5 * radius * w * math.sin(a)]
        elif kind == "figure8":
            p = [radius * math.sin(a), radius * math.sin(a) * math.cos(a), 0.0]
            v = [radius * w * math.cos(a), radius * w * math.cos(2 * a), 0.0]
        else:
            p, v = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
        return c + np.array(p), np.array(v)

    return motion


def recorded_motion(path: str | Path) -> HandleMotion:
    """A handle replaying a CSV with columns ``t, x, y, z`` (s, m; header row), interpolated, in a loop."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not rows or not {"t", "x", "y", "z"} <= set(rows[0]):
        raise ValueError(f"{path}: needs a header row with columns t, x, y, z and at least two rows")
    try:
        data = np.array([[float(r[k]) for k in ("t", "x", "y", "z")] for r in rows])
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    t = data[:, 0] - data[0, 0]
    if len(t) < 2 or not np.all(np.diff(t) > 0) or not np.isfinite(data).all():
        raise ValueError(f"{path}: needs at least two rows, finite values and increasing t")
    span = t[-1]
    velocity = np.diff(data[:, 1:], axis=0) / np.diff(t)[:, None]

    def motion(now: float) -> tuple[np.ndarray, np.ndarray]:
        s = now % span
        p = np.array([np.interp(s, t, data[:, k]) for k in (1, 2, 3)])
        return p, velocity[min(int(np.searchsorted(t, s, side="right")) - 1, len(velocity) - 1)].copy()

    return motion
