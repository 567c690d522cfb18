"""What a review reports per contact and per estimator, and the running figures that compute it chunk by chunk.

Each fold takes a chunk of samples and keeps only sums, extremes and the
current run, so a review's memory does not grow with the session:

* :class:`Envelope`: time-binned min, max and mean of a series (the plots);
* :class:`Moments`: per-axis count, mean, M2 (Chan's merge), Σ|x| and max|x|
  (the paper's MAE, Max AE and Std, as ``metrics.error_stats`` computes them
  on whole arrays: a test checks they agree);
* :class:`EstimatorFold`: one estimator's convergence and its paper table;
* :class:`ContactFold`: contact runs, time over the force limit, the peak.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hapticlab.sessions.offline.metrics import mae_compensation_pct

MERGE_GAP_S = 0.1
"""Two contact runs closer than this, s, are one contact (the flag flickers at the threshold)."""
BINS = 1200
"""Time bins of the plots' envelopes (min, max and mean per bin: every sample is in one)."""
AXES = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass
class Contact:
    """One contact: when, how long, how hard (‖contact force‖, N)."""

    start_s: float
    duration_s: float
    peak_N: float
    mean_N: float
    over_limit_s: float


@dataclass
class EstimatorReview:
    """One estimator's run in the session.

    Attributes:
        name: its topic's label (``/estimator/<name>``).
        samples: samples it estimated.
        converged_force_s, converged_torque_s: first time each stage's flag was up, s from the start (None: never).
        converged_at_end: the force stage's flag on the last sample.
        table: the paper's table per axis (``metrics.error_stats`` keys), None when it never converged or
            no no-contact sample followed.
        scored: samples scored in the table (force axes).
    """

    name: str
    samples: int = 0
    converged_force_s: float | None = None
    converged_torque_s: float | None = None
    converged_at_end: bool = False
    table: dict[str, dict[str, float]] | None = None
    scored: int = 0


@dataclass
class Envelope:
    """Time-binned min, max and mean of a (k,)-valued series over [t0_ns, t1_ns] (for plots)."""

    t0_ns: int
    t1_ns: int
    width: int
    bins: int = BINS
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)
    total: np.ndarray = field(init=False)
    count: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.lo = np.full((self.bins, self.width), np.nan)
        self.hi = np.full((self.bins, self.width), np.nan)
        self.total = np.zeros((self.bins, self.width))
        self.count = np.zeros((self.bins, self.width), np.int64)

    def add(self, t_ns: np.ndarray, values: np.ndarray) -> None:
        values = np.asarray(values, float).reshape(len(t_ns), self.width)
        span = max(self.t1_ns - self.t0_ns, 1)
        idx = np.clip((np.asarray(t_ns, np.int64) - self.t0_ns) * self.bins // span, 0, self.bins - 1)
        if not len(idx):
            return
        finite = np.isfinite(values)
        if np.all(idx[1:] >= idx[:-1]):  # in time order (always, from a recording): one reduction per run of a bin
            starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
            b = idx[starts]
            self.lo[b] = np.fmin(self.lo[b], np.fmin.reduceat(values, starts, axis=0))
            self.hi[b] = np.fmax(self.hi[b], np.fmax.reduceat(values, starts, axis=0))
            self.total[b] += np.add.reduceat(np.where(finite, values, 0.0), starts, axis=0)
            self.count[b] += np.add.reduceat(finite.astype(np.int64), starts, axis=0)
            return
        np.fmin.at(self.lo, idx, values)
        np.fmax.at(self.hi, idx, values)
        np.add.at(self.total, idx, np.where(finite, values, 0.0))
        np.add.at(self.count, idx, finite)

    @property
    def t_s(self) -> np.ndarray:
        """(bins,) the bins' centres, s from t0."""
        span = (self.t1_ns - self.t0_ns) / 1e9
        return (np.arange(self.bins) + 0.5) * span / self.bins

    @property
    def mean(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 0, self.total / np.maximum(self.count, 1), np.nan)


class Moments:
    """Per-axis count, mean, M2 (Chan's merge), sum of |x| and max |x| over chunks of rows."""

    def __init__(self, k: int):
        self.n = np.zeros(k)
        self.mean = np.zeros(k)
        self.m2 = np.zeros(k)
        self.abs_sum = np.zeros(k)
        self.abs_max = np.zeros(k)

    def add(self, x: np.ndarray) -> None:
        if not len(x):
            return
        nb = len(x)
        mean_b = x.mean(axis=0)
        m2_b = ((x - mean_b) ** 2).sum(axis=0)
        n = self.n + nb
        delta = mean_b - self.mean
        self.mean = self.mean + delta * nb / n
        self.m2 = self.m2 + m2_b + delta**2 * self.n * nb / n
        self.n = n
        self.abs_sum += np.abs(x).sum(axis=0)
        self.abs_max = np.maximum(self.abs_max, np.abs(x).max(axis=0))

    def stats(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(MAE, Max AE, Std) per axis (population Std, as the paper's)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.abs_sum / self.n, self.abs_max, np.sqrt(self.m2 / self.n)


class EstimatorFold:
    """One estimator's samples folded chunk by chunk (with the raw reading of each)."""

    def __init__(self, name: str, t0_ns: int):
        self.review = EstimatorReview(name)
        self.t0_ns = t0_ns
        self.first_force_ns: int | None = None
        self.first_torque_ns: int | None = None
        self.before = [Moments(3), Moments(3)]  # force, torque
        self.after = [Moments(3), Moments(3)]
        self.scored = [0, 0]

    def add(self, c: dict[str, np.ndarray]) -> None:
        r = self.review
        r.samples += len(c["t_ns"])
        for stage, key in ((0, "converged_force"), (1, "converged_torque")):
            flags = c[key].astype(bool)
            first = self.first_force_ns if stage == 0 else self.first_torque_ns
            if first is None and flags.any():
                first = int(c["t_ns"][np.argmax(flags)])
                if stage == 0:
                    self.first_force_ns = first
                else:
                    self.first_torque_ns = first
            if first is None:
                continue
            raw = c["raw_force"] if stage == 0 else c["raw_torque"]
            est = c["contact_force_S"] if stage == 0 else c["contact_torque_S"]
            rows = (c["t_ns"] >= first) & ~c["contact"].astype(bool) & np.isfinite(raw).all(1) & np.isfinite(est).all(1)
            self.before[stage].add(raw[rows])
            self.after[stage].add(est[rows])
            self.scored[stage] += int(rows.sum())
        r.converged_at_end = bool(c["converged_force"][-1])

    def finish(self) -> EstimatorReview:
        r = self.review
        to_s = lambda t: None if t is None else (t - self.t0_ns) / 1e9  # noqa: E731
        r.converged_force_s, r.converged_torque_s = to_s(self.first_force_ns), to_s(self.first_torque_ns)
        r.scored = self.scored[0]
        if self.scored[0] or self.scored[1]:
            table = {}
            for stage in (0, 1):
                (mae_b, max_b, std_b), (mae_a, max_a, std_a) = self.before[stage].stats(), self.after[stage].stats()
                for k in range(3):
                    table[AXES[3 * stage + k]] = {
                        "mae_before": float(mae_b[k]),
                        "max_before": float(max_b[k]),
                        "std_before": float(std_b[k]),
                        "mae_after": float(mae_a[k]),
                        "max_after": float(max_a[k]),
                        "std_after": float(std_a[k]),
                        "mae_comp_pct": mae_compensation_pct(float(mae_b[k]), float(mae_a[k])),
                        "samples": self.scored[stage],
                    }
            r.table = table
        return r


class ContactFold:
    """Contact runs, the time over the limit and the peak, from the primary estimator's samples."""

    def __init__(self, t0_ns: int, limit: float, period_s: float):
        self.t0_ns, self.limit, self.period_s = t0_ns, limit, period_s
        self.contacts: list[Contact] = []
        self.open: list[float] | None = None  # [start_ns, last_ns, peak, sum, n, over]
        self.over_limit_s = 0.0
        self.peak = float("nan")
        self.contact_samples = 0

    def add(self, t_ns: np.ndarray, contact: np.ndarray, force: np.ndarray) -> None:
        over = np.nan_to_num(force) > self.limit
        self.over_limit_s += int(over.sum()) * self.period_s
        if len(force) and np.isfinite(force).any():
            self.peak = float(np.nanmax([np.nan_to_num(self.peak, nan=-np.inf), np.nanmax(force)]))
        idx = np.flatnonzero(contact)
        self.contact_samples += len(idx)
        if not len(idx):
            return
        # runs of contact samples: a new run where the time gap to the previous contact sample is large
        t = t_ns[idx]
        gap_ns = MERGE_GAP_S * 1e9
        breaks = np.flatnonzero(np.diff(t) > gap_ns) + 1
        starts = np.concatenate(([0], breaks))
        ends = np.concatenate((breaks, [len(idx)]))
        for s, e in zip(starts, ends):
            f = np.nan_to_num(force[idx[s:e]])
            run = [float(t[s]), float(t[e - 1]), float(f.max()), float(f.sum()), e - s, int((f > self.limit).sum())]
            if self.open is not None and run[0] - self.open[1] <= gap_ns:
                o = self.open
                self.open = [o[0], run[1], max(o[2], run[2]), o[3] + run[3], o[4] + run[4], o[5] + run[5]]
            else:
                self._close()
                self.open = run

    def _close(self) -> None:
        if self.open is None:
            return
        start, last, peak, total, n, over = self.open
        self.contacts.append(
            Contact(
                (start - self.t0_ns) / 1e9,
                (last - start) / 1e9 + self.period_s,
                float(peak),
                float(total / n),
                over * self.period_s,
            )
        )
        self.open = None

    def finish(self) -> list[Contact]:
        self._close()
        return self.contacts
