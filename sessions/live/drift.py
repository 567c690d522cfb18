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
same misfit (a bin's mean of noise alike on the three axes is the same size in any frame), and so does
a tool that does not turn (then nothing can be told, and nothing is said). The verdict:

* ``"sensor"``: the residual is at least ``MIN_OFFSET_N``, the fit in S misses by about the noise
  (``NOISE_MISFIT_N``) and by ``RATIO`` times less than the fit in B, and B's misses by at least
  ``EXCESS_N`` more (in quadrature): the residual kept its direction in the sensor while the tool turned;
* ``"world"``: the same with S and B swapped (the noise bound aside: a contact's size varies): it kept
  its direction in the world (a contact).

The contacts this cannot tell from a bias are those whose direction is tied to the tool, not the
world: a needle's shaft friction while the tool pivots about the needle, a push and a pull along the
shaft (a line through the origin fits both). docs/safety.md says so.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

BIN_NS = 20_000_000
"""One mean per this long of samples, ns: 20 samples of a 1 kHz sensor, whose noise (0.12 N per axis,
Gamma class) averages down to 0.027 N per axis, so a fit's misfit of noise alone is about 0.038 N."""
WINDOW_BINS = 25
"""The fits span this many bins (0.5 s). A force of size m swept through θ rad by the tool's turn misses
a fixed direction by about m·θ/√12 RMS: at the demo tour's half a radian in 0.5 s, 0.14·m, so the verdict
(``RATIO``) needs m ≳ 0.5 N there, less where the tool turns faster; a longer window would see more turn
but answer later (and, in a contact, hold the force longer)."""
MIN_OFFSET_N = 0.25
"""Smaller residuals are left alone, N: about five times a bin's noise (norm), and under the estimators'
contact thresholds."""
NOISE_MISFIT_N = 0.08
"""A sensor verdict also needs the fit in S to miss by no more than this, N: about twice the misfit of
noise alone (``BIN_NS``). A bias with a contact beside it (the contact turning in S) misses by more, and
is no verdict: the bias is re-identified only once the contact has gone."""
EXCESS_N = 0.05
"""The other frame's fit must miss by this much more (in quadrature), N. At the default noise the ratio
(``RATIO``) binds first; on a quiet sensor this keeps a difference of a few hundredths of a newton from
being a verdict."""
RATIO = 2.0
"""...and miss by this factor (RMS) more than the frame the residual keeps its direction in."""
WEIGHT_TILT = 0.25
"""A sudden step whose force keeps its direction in the world within this angle of the weight's (a pull
down: a load hung on the tool, or the support it started resting on gone) is taken for a weight change, not
a contact, rad (``plugins.estimators.kalman.payload.MAX_TILT``). A push up is a contact's (a tool pressed on
bone) or a load let go; kalman's payload test tells the second."""


def misfit(means: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(size, misfit, direction) of (n, 3) means: the RMS along their best single direction through the
    origin (the largest singular value / √n), N; the RMS off it (the other two), N; that direction (3,),
    its sign that of the means' sum along it."""
    _, s, Vt = np.linalg.svd(means, full_matrices=False)
    n = len(means)
    u = Vt[0] if float(means.sum(axis=0) @ Vt[0]) >= 0 else -Vt[0]
    return float(s[0]) / n**0.5, float(np.sqrt((s[1] ** 2 + s[2] ** 2) / n)), u


def along(u: np.ndarray, v: list[float], angle: float) -> bool:
    """``u`` (unit) points the way ``v`` does, within ``angle`` rad."""
    norm = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    return norm > 0 and float(u[0] * v[0] + u[1] * v[1] + u[2] * v[2]) / norm >= math.cos(angle)


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
        self.last_ns: int | None = None  # the newest sample's stamp
        self.R_EB_last = np.eye(3)  # the newest sample's orientation
        self.total = [0.0, 0.0, 0.0]
        self.count = 0
        self.means_S: deque[list[float]] = deque(maxlen=WINDOW_BINS)
        self.means_B: deque[list[float]] = deque(maxlen=WINDOW_BINS)
        self.offset_S = np.zeros(3)
        self.size = math.inf  # the last full window's residual along its direction (RMS), N; inf until one is full
        self.direction_B = np.zeros(3)  # the last full window's direction in B (unit; zero until one is full)
        self.misfits = (0.0, 0.0)  # the last fits' misfits in S and in B, N (for the event's message)

    def add(self, t_ns: np.ndarray, contact_force_S: np.ndarray, R_EB: np.ndarray, R_SE: np.ndarray | None) -> str:
        """One block the primary estimator refined: stamps (n,) ns, its contact force (n, 3) N in S, the
        orientations R_EB (n, 3, 3) and the sensor's mount R_SE (3, 3; None: S is E); the verdict of the bins
        it closed ("" none). Samples further apart than a bin (withheld meanwhile) start the window afresh:
        what the tool did in between is unknown. Non-finite rows are skipped."""
        verdict = ""
        for k, (t, f) in enumerate(zip(t_ns.tolist(), contact_force_S.tolist())):
            if not (math.isfinite(f[0]) and math.isfinite(f[1]) and math.isfinite(f[2])):
                continue
            if self.last_ns is not None and t - self.last_ns > BIN_NS:
                self.reset()
            if self.bin_start_ns is None:
                self.bin_start_ns = t
            elif t - self.bin_start_ns >= BIN_NS:
                verdict = self._close(R_SE) or verdict
                self.bin_start_ns = t
            total = self.total
            total[0] += f[0]
            total[1] += f[1]
            total[2] += f[2]
            self.count += 1
            self.last_ns, self.R_EB_last = t, R_EB[k]
        return verdict

    def _close(self, R_SE: np.ndarray | None) -> str:
        """Close the bin in hand (its rotation: that of its last sample) and judge the window."""
        mean_S = np.array(self.total) / self.count
        R_EB = self.R_EB_last
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
        if in_B**2 - in_S**2 >= EXCESS_N**2 and in_S * RATIO <= in_B and in_S <= NOISE_MISFIT_N:
            return "sensor"
        if in_S**2 - in_B**2 >= EXCESS_N**2 and in_B * RATIO <= in_S:
            return "world"
        return ""
