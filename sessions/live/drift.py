"""Which frame the residual lives in: a sensor's bias moving, or a contact from the world.

After a knock, a temperature change or a slow thermal drift the sensor's zero moves, and a converged
estimator sees a "contact" that is not there. A real contact acts on the tool from outside: its
direction is set by the world (the tissue's surface, the thing the tool pushes on), so when the tool
turns the contact turns in the sensor frame S and keeps its direction in the base frame B. A bias
lives in the sensor: it keeps its direction in S whatever the tool does, and turns in B.

:class:`DriftWatch` keeps the estimator's contact force (its residual) of the last ``WINDOW_BINS``
bins of ``BIN_NS`` each, as means in S and in B, and fits each set of means with one direction
through the origin (its magnitude free: a drift that grows, a contact that rises and falls). The part
of the means off that direction is the fit's misfit (RMS, N); the sensor's noise gives both fits the
same misfit (a bin's mean of noise is the same size in any frame), and so does a tool that does not
turn (then nothing can be told, and nothing is said). The verdict:

* ``"sensor"``: the residual is at least ``MIN_OFFSET_N``, the fit in S leaves no more than the
  noise (its misfit squared at most ``1 / RATIO²`` of B's) and the fit in B misses by at least
  ``EXCESS_N`` more than it: the residual kept its direction in the sensor while the tool turned;
* ``"world"``: the same with S and B swapped: it kept its direction in the world (a contact).

The one contact this cannot tell from a bias is one whose direction is tied to the tool, not the
world: a needle's shaft friction while the tool pivots about the needle. docs/safety.md says so.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

BIN_NS = 20_000_000
"""One mean per this long of samples, ns: 20 samples of a 1 kHz sensor, whose noise (0.12 N per axis,
Gamma class) averages down to 0.027 N per axis."""
WINDOW_BINS = 25
"""The fits span this many bins (0.5 s): the demo's tour turns the tool about half a radian in that
time, enough to move a 0.3 N force by ~0.15 N, and a drift of 0.5 N/s grows by only 0.25 N."""
MIN_OFFSET_N = 0.25
"""Smaller residuals are left alone (about twice a bin's noise, and under the estimators' contact
thresholds), N."""
EXCESS_N = 0.05
"""The other frame's fit must miss by this much more (in quadrature) than the noise, N: about five
times the spread of a 25-bin misfit of noise alone."""
RATIO = 2.0
"""...and miss by this factor (RMS) more than the frame the residual keeps its direction in."""


def misfit(means: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(size, misfit, direction) of (n, 3) means: the RMS along their best single direction through the
    origin (the largest singular value / √n), N; the RMS off it (the other two), N; that direction (3,),
    its sign that of the means' sum along it."""
    _, s, Vt = np.linalg.svd(means, full_matrices=False)
    n = len(means)
    u = Vt[0] if float(means.sum(axis=0) @ Vt[0]) >= 0 else -Vt[0]
    return float(s[0]) / n**0.5, float(np.sqrt((s[1] ** 2 + s[2] ** 2) / n)), u


def along(u: np.ndarray, v: list[float], angle: float) -> bool:
    """``u`` (unit) and ``v`` point along the same line, either way, within ``angle`` rad."""
    norm = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    return norm > 0 and abs(float(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])) / norm >= math.cos(angle)


class DriftWatch:
    """Tells a residual fixed in the sensor (a bias step or drift) from one fixed in the world (a contact).

    ``add`` takes each block the primary estimator refined and returns ``"sensor"``, ``"world"`` or ``""``
    (see the module); ``offset_S`` is then the newest bin's mean in S, (3,) N; ``size`` the last full
    window's residual (RMS along its direction), N, for the gate to see it settle, and ``direction_B`` that
    direction in B (a world verdict along gravity is a weight's). Per sample the work is a
    running sum in Python floats (a live block is one to seven samples); the fits run once a bin.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget every bin (after a verdict was acted on, or the bias was re-identified)."""
        self.bin_start_ns: int | None = None
        self.total = [0.0, 0.0, 0.0]
        self.count = 0
        self.means_S: deque[list[float]] = deque(maxlen=WINDOW_BINS)
        self.means_B: deque[list[float]] = deque(maxlen=WINDOW_BINS)
        self.offset_S = np.zeros(3)
        self.size = math.inf  # the last full window's residual along its direction (RMS), N; inf until one is full
        self.direction_B = np.zeros(3)  # the last full window's direction in B (unit; zero until one is full)
        self.misfits = (0.0, 0.0)  # the last fits' misfits in S and in B, N (for the event's message)

    def add(self, t_ns: np.ndarray, contact_force_S: np.ndarray, R_EB: np.ndarray, R_SE: np.ndarray | None) -> str:
        verdict = ""
        total = self.total
        for k, (t, f) in enumerate(zip(t_ns.tolist(), contact_force_S.tolist())):
            if f[0] != f[0] or f[1] != f[1] or f[2] != f[2]:  # NaN (never expected of an estimate): skipped
                continue
            if self.bin_start_ns is None:
                self.bin_start_ns = t
            elif t - self.bin_start_ns >= BIN_NS:
                verdict = self._close(R_EB[k], R_SE) or verdict
                self.bin_start_ns = t
            total[0] += f[0]
            total[1] += f[1]
            total[2] += f[2]
            self.count += 1
        return verdict

    def _close(self, R_EB: np.ndarray, R_SE: np.ndarray | None) -> str:
        """Close the bin in hand (its rotation: ``R_EB`` of the sample after it) and judge the window."""
        mean_S = np.array(self.total) / self.count
        self.total, self.count = [0.0, 0.0, 0.0], 0
        R_BS = R_EB.T if R_SE is None else R_EB.T @ R_SE.T
        self.means_S.append(mean_S.tolist())
        self.means_B.append((R_BS @ mean_S).tolist())
        self.offset_S = mean_S
        if len(self.means_S) < WINDOW_BINS:
            return ""
        size, in_S, _ = misfit(np.array(self.means_S))
        _, in_B, self.direction_B = misfit(np.array(self.means_B))
        self.size, self.misfits = size, (in_S, in_B)
        if size < MIN_OFFSET_N:
            return ""
        if in_B**2 - in_S**2 >= EXCESS_N**2 and in_S * RATIO <= in_B:
            return "sensor"
        if in_S**2 - in_B**2 >= EXCESS_N**2 and in_B * RATIO <= in_S:
            return "world"
        return ""
