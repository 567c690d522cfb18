"""The skill metrics of one recording, gathered as the review streams it (``skill.py`` computes them).

:class:`SkillFold` takes the primary estimator's ‖contact force‖ a chunk at a time: at full rate for the
force–time integral and the time in the task's force band; as 10 ms bin means (:data:`BIN_S`) for the
force's derivative and SPARC; as 10 ms bin maxima for the excessive-force events (a spike of one sample
over the limit is one). It also takes the robot's targets (``/robot/target``: the path, the time following,
holding and clutching, the place of each mark) and the master's buttons (``/haptic/state``: the marks).
Memory: eight floats per 10 ms (~23 MB an hour), whatever the sensor's rate.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hapticlab.sessions.review import skill
from hapticlab.sessions.review.figures import MERGE_GAP_S, Contact

BIN_S = 0.01
"""The force profile the derivative and SPARC read: 10 ms means (100 Hz; SPARC looks below 10 Hz)."""


class SkillFold:
    """Running figures for :func:`skill.*` (``add_force``, ``add_targets``, ``add_states``; then ``finish``).

    Args:
        t0_ns: the session's start, ns.
        force_limit: the limit excessive-force events are counted above, N.
        band: [low, high] N of the force band the time in band counts (retraction), or None.
        mark_button: the button bit whose presses are marks (palpation), or -1.
    """

    period_s = 1e-3
    """The sensor's period, s (each sample holds for one): set by the review once it knows it."""

    def __init__(self, t0_ns: int, force_limit: float, band=None, mark_button: int = -1):
        self.t0, self.force_limit = t0_ns, force_limit
        self.band, self.mark_bit = band, mark_button
        self.bins: list[tuple[np.ndarray, ...]] = []  # (bin index, sum, count, max) per chunk
        self.fti = 0.0  # N·s in contact
        self.in_band_s = 0.0
        self.path_m = 0.0
        self.mode_s = {"following": 0.0, "holding": 0.0, "clutching": 0.0}
        self.last_target: tuple[int, np.ndarray, str] | None = None  # (t_ns, p, mode)
        self.first_following: tuple[int, np.ndarray] | None = None
        self._target_t: list[np.ndarray] = []  # s, and the flange (m), every BIN_S: the tracing error, the marks
        self._target_p: list[np.ndarray] = []
        self._target_last_s = -math.inf
        self.buttons = 0
        self.marks_ns: list[int] = []

    def add_force(self, t_ns: np.ndarray, force: np.ndarray, contact: np.ndarray) -> None:
        """The primary estimator's samples: stamps (ns), ‖contact force‖ (N) and its contact flag."""
        force = np.where(np.isfinite(force), force, 0.0)
        touching = force[contact]
        self.fti += skill.force_time_integral(touching, self.period_s)
        if self.band is not None:
            low, high = self.band
            self.in_band_s += float(np.count_nonzero((touching >= low) & (touching <= high))) * self.period_s
        k = ((t_ns - self.t0) // round(BIN_S * 1e9)).astype(np.int64)
        keys, where = np.unique(k, return_inverse=True)
        peak = np.full(len(keys), -np.inf)
        np.maximum.at(peak, where, force)
        self.bins.append((keys, np.bincount(where, weights=force), np.bincount(where).astype(float), peak))

    def add_targets(self, batch: dict[str, np.ndarray]) -> None:
        """``/robot/target`` as columns (``t_ns``, ``p_BoEo_B`` m, ``mode``, ``reason``), in order: the path, the
        time per mode, the flange where marks fall."""
        t, p = batch["t_ns"].astype(np.int64), batch["p_BoEo_B"]
        if not len(t):
            return
        holding = batch["mode"] == "holding"
        clutch = np.array([str(r).startswith("clutch") for r in batch["reason"]], dtype=bool)
        modes = np.where(holding & clutch, "clutching", batch["mode"]).astype(object)
        if self.last_target is not None:  # joined to the previous batch's last target
            t_last, p_last, mode_last = self.last_target
            t, p, modes = np.concatenate(([t_last], t)), np.vstack((p_last, p)), np.concatenate(([mode_last], modes))
        steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
        self.path_m += float(steps[np.isfinite(steps)].sum())
        dt = np.diff(t) / 1e9
        for mode in self.mode_s:  # each interval counts for the mode it started in
            self.mode_s[mode] += float(dt[modes[:-1] == mode].sum())
        following = np.flatnonzero(modes == "following")
        if self.first_following is None and len(following):
            self.first_following = (int(t[following[0]]), p[following[0]])
        t_s = (t - self.t0) / 1e9
        first = np.flatnonzero(np.diff(np.floor(np.concatenate(([self._target_last_s], t_s)) / BIN_S)) > 0)
        if len(first):  # the first target of each BIN_S
            self._target_t.append(t_s[first])
            self._target_p.append(p[first])
            self._target_last_s = float(t_s[first[-1]])
        self.last_target = (int(t[-1]), p[-1], modes[-1])

    def add_states(self, batch: dict[str, np.ndarray]) -> None:
        """``/haptic/state`` as columns (``t_ns``, ``buttons``), in order: each press (an edge) of the mark
        button is a mark."""
        if self.mark_bit < 0 or not len(batch["t_ns"]):
            return
        buttons = np.nan_to_num(batch["buttons"]).astype(np.int64)
        down = (buttons >> self.mark_bit) & 1
        before = np.concatenate(([(self.buttons >> self.mark_bit) & 1], down[:-1]))
        self.marks_ns.extend(batch["t_ns"][(down == 1) & (before == 0)].astype(np.int64).tolist())
        self.buttons = int(buttons[-1])

    def targets(self) -> tuple[np.ndarray, np.ndarray]:
        """The flange's targets, the first of each :data:`BIN_S`: (t (k,) s from the start, p (k, 3) m in B)."""
        if not self._target_t:
            return np.zeros(0), np.zeros((0, 3))
        return np.concatenate(self._target_t), np.concatenate(self._target_p)

    def _marks(self, t: np.ndarray, p: np.ndarray) -> list[tuple[float, np.ndarray]]:
        """Each mark: (t s, the flange's target then, m in B: the newest target at or before it)."""
        if not len(t):
            return []
        seconds = [(t_ns - self.t0) / 1e9 for t_ns in self.marks_ns]
        return [(s, p[max(0, int(np.searchsorted(t, s, side="right")) - 1)]) for s in seconds]

    def profile(self) -> tuple[np.ndarray, np.ndarray]:
        """The 10 ms means and maxima of ‖contact force‖ over the session (N; NaN where no sample fell)."""
        if not self.bins:
            return np.zeros(0), np.zeros(0)
        keys = np.concatenate([b[0] for b in self.bins])
        total = np.zeros(int(keys.max()) + 1)
        count = np.zeros_like(total)
        peak = np.full_like(total, -np.inf)
        for k, s, c, m in self.bins:
            np.add.at(total, k, s)
            np.add.at(count, k, c)
            np.maximum.at(peak, k, m)
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / count, np.where(count > 0, peak, np.nan)

    def finish(self, contacts: list[Contact], contact_s: float, over_limit_s: float) -> dict[str, Any]:
        """The metrics (keys of ``skill_names``, but the task's score) and what the task's score reads."""
        mean, peak = self.profile()
        rates, smooth, weights = [], [], []
        for c in contacts:
            seg = mean[int(c.start_s / BIN_S) : math.ceil((c.start_s + c.duration_s) / BIN_S)]
            seg = seg[np.isfinite(seg)]
            rates.append(skill.force_rate(seg, BIN_S))
            smooth.append(skill.sparc(seg, 1.0 / BIN_S))
            weights.append(c.duration_s)
        # every sample counts (a 2 ms spike over the limit is an event): on each bin's largest
        starts = np.arange(len(peak)) * BIN_S
        events = skill.excess_force_events(starts, np.nan_to_num(peak), self.force_limit, MERGE_GAP_S)
        start_s = (self.first_following[0] - self.t0) / 1e9 if self.first_following else None
        if start_s is None and contacts:
            start_s = contacts[0].start_s
        end = max((c.start_s + c.duration_s for c in contacts), default=None)
        target_t, target_p = self.targets()
        return {
            "task_time_s": end - start_s if end is not None and start_s is not None and end > start_s else None,
            "force_time_integral_Ns": self.fti,
            "mean_force_rate_N_s": _weighted([r[0] for r in rates], weights),
            "max_force_rate_N_s": _finite_max([r[1] for r in rates]),
            "sparc": _weighted(smooth, weights),
            "excess_force_events": len(events),
            "excess_force_time_s": over_limit_s,
            "contact_time_s": contact_s,
            "path_length_m": self.path_m if self.last_target is not None else None,
            "following_time_s": self.mode_s["following"] if self.last_target is not None else None,
            "holding_time_s": self.mode_s["holding"] if self.last_target is not None else None,
            "clutching_time_s": self.mode_s["clutching"] if self.last_target is not None else None,
            "events": events,
            "in_band_s": self.in_band_s,
            "start_s": start_s,
            "first_p": None if self.first_following is None else self.first_following[1],
            "marks": self._marks(target_t, target_p),
            "targets": (target_t, target_p),
            "contacts": [(c.start_s, c.start_s + c.duration_s) for c in contacts],
        }


def _weighted(values: list[float], weights: list[float]) -> float | None:
    pairs = [(v, w) for v, w in zip(values, weights, strict=True) if math.isfinite(v) and w > 0]
    total = sum(w for _, w in pairs)
    return sum(v * w for v, w in pairs) / total if total > 0 else None


def _finite_max(values: list[float]) -> float | None:
    finite = [v for v in values if math.isfinite(v)]
    return max(finite) if finite else None
