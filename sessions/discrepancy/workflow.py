"""``hapticlab discrepancy``: where simulation and measurement disagree, which effect is missing, and the gap shrinking.

On a measured recording (CSV import contract or MCAP):

1. **Identify and simulate.** The base model (the paper's, with the weight's
   moment from the predicted weight) is fitted by weighted least squares
   (Gauss–Newton, force block from the forces, then torque block from the
   torques), started robustly: from the offline batch fit, trimmed least
   squares (the half of the rows that fit best, re-chosen until it settles),
   so contact over anything under half the recording cannot pull the start.
   The sensor is simulated along the recorded motion with it. Each channel is
   weighted by its noise, estimated from the residual's sample-to-sample
   differences (robust: MAD), so forces and torques count alike.
2. **Gate contact.** Samples whose residual is more than ``gate_sigmas``
   robust standard deviations (MAD) off on any channel are set aside, with
   ``gate_dilate_s`` either side when ``t`` is a time; fit and gate are
   iterated until the gate settles, and again after every step. A gate that
   would set aside half of the samples is not applied, and the result says so
   (``warnings.gate_not_applied`` and a note), as it does when the final RMS
   stays above ``warn_rms_over_noise`` (1.5) times the noise estimate.
3. **Test every candidate effect** (the ``effect`` plugins not yet added)
   against the residual on held-out data: blocked cross-validation over time,
   ``folds`` contiguous folds of the kept samples (at least ``min_folds``, 5,
   smaller ones on short recordings), each held out in turn with a buffer of
   one fifth of a fold either side left out of its training set (residuals
   are correlated in time). Model and model-plus-candidate are both re-fitted
   on the training folds (one Gauss–Newton step from the current fit) and
   scored on the held-out fold.
4. **Name** the candidate that best explains the held-out residual, if it is
   significant: it lowers the held-out mean square (noise-weighted) by at
   least ``min_gain`` (1 %), summed over the folds, and in at least
   ``min_fold_share`` of the folds (80 %) and in enough of them for a one-sided
   sign test of at most ``max_sign_p`` (5.5 %: 8 of 10, 5 of 5; below 5 folds
   nothing passes). The t statistic over the folds is reported, not used. Add
   it, re-identify everything, re-gate, test every effect named before again
   beside it (dropped when no longer significant), repeat until no candidate
   is significant.
5. **The structure test**: a named effect must explain at least
   ``min_structure_share`` (50 %) of the structure (each channel's excess over
   its own noise) the model leaves without it, or it is set aside, reported,
   not named: an effect outside the library gains on held-out data as some
   library term that leaves most of the structure in place.
6. **Show the gap shrink**: RMS per axis before and after each step (every
   figure on the final gate's samples), against the offline batch fit, plots,
   and JSON (``DESIGN.md``) with the ``kalman`` options that reproduce the
   named effects online.

Large recordings are fitted and tested on at most ``max_fit_samples``
samples (every k-th, evenly spread); the RMS figures use every sample.
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from hapticlab.core.estimation.batch import batch_fit
from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.sensor_model.model import Effect, LocatesItself, Model, Motion, motion_from_poses
from hapticlab.sessions.discrepancy.blas import single_threaded_blas
from hapticlab.sessions.discrepancy.leftover import axis_noise, leftover_threshold, where_left, where_text
from hapticlab.sessions.offline.metrics import rms
from hapticlab.sessions.offline.numerics import numerical_failures
from hapticlab.sessions.recording.csvimport import CsvError
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.stream import Stream

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass
class Settings:
    """Knobs of the workflow (defaults are the documented rule)."""

    folds: int = 10
    min_gain: float = 0.01
    min_fold_share: float = 0.8
    max_sign_p: float = 0.055
    """the fold wins must also be a one-sided sign test at least this strong (8 of 10 folds: 5.5 %)"""
    min_folds: int = 5
    """short recordings get at least this many (smaller) folds: fewer cannot pass the sign test"""
    trim_share: float = 0.5
    """the robust start fits the base model on this share of the rows that fit it best"""
    warn_rms_over_noise: float = 1.5
    gate_sigmas: float = 6.0
    gate_dilate_s: float = 0.25
    max_fit_samples: int = 20000
    derivative_window_s: float = 0.04
    min_structure_share: float = 0.5
    """a named effect must remove at least this share of the structure (excess over the noise) the model
    leaves without it (``Discrepancy.structure_test``)"""
    time_base: str = "auto"
    effects: list[str] | None = None
    """candidate effect names (None: every registered one)"""
    effect_options: dict[str, dict[str, Any]] = field(default_factory=dict)
    """options per effect name, e.g. {"bias_drift": {"order": 2}}"""


# --------------------------------------------------------------------------- input


def detect_time_base(t: np.ndarray) -> str:
    """``"index"`` when ``t`` counts rows (integers in steps of one), else ``"seconds"``."""
    if len(t) > 1 and np.all(t == np.round(t)) and np.all(np.diff(t) == 1.0):
        return "index"
    return "seconds"


def recorded_motion(stream: Stream, time_base: str = "auto", window_s: float = 0.04) -> tuple[Motion, list[str]]:
    """The motion the workflow fits along (poses and derivatives at every row), and notes on the input.

    ``time_base`` ``"auto"`` takes a ``t`` that counts rows for what it is
    (no derivatives, so no time-based effects); the derivatives are
    Savitzky–Golay fits ``window_s`` wide. A stream with fewer than 20 (usable)
    rows is a ``CsvError``.
    """
    if time_base not in ("auto", "seconds", "index"):
        raise ConfigError(f"--time-base: expected auto, seconds or index, got {time_base!r}")
    samples, name, n = stream.samples, stream.name, len(stream)
    if n < 20:
        raise CsvError(f"{name}: {n} rows; the workflow needs at least 20")
    usable = int(samples.usable.sum())
    if usable < 20:
        raise CsvError(f"{name}: only {usable} usable rows; the workflow needs at least 20")
    t = np.asarray(stream.t_s, dtype=float)
    notes = []
    base = detect_time_base(t) if time_base == "auto" else time_base
    if base == "index" and time_base == "auto":
        notes.append(
            f"{name}: t counts rows (0, 1, 2, ...), not seconds: the time-based effects "
            f"(time_lag, inertia) cannot be tested; use --time-base seconds if it is a time"
        )
    if base == "seconds":
        dt = np.diff(t)
        if dt.max() > 3 * np.median(dt):
            notes.append(
                f"{name}: the sampling has gaps (up to {dt.max():.3g} s against a median "
                f"{np.median(dt):.3g} s); derivatives next to them are unreliable"
            )
    quat = samples.quat_BE if samples.quat_BE is not None else quat_wxyz_from_matrix(samples.R_EB.transpose(0, 2, 1))
    positions = samples.p_BoEo_B
    if positions is not None and not np.isfinite(positions).all():
        positions = None
    return motion_from_poses(t, quat, positions, base, window_s), notes


# --------------------------------------------------------------------------- numerics


def solve_scaled(H: np.ndarray, g: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Minimum-norm solution of H δ = g after scaling H to a unit diagonal (parameters of mixed units).

    Directions the data do not determine (eigenvalues below ``rcond`` of the
    largest) are left at zero.
    """
    d = np.sqrt(np.maximum(np.diag(H), 0.0))
    d[d == 0] = 1.0
    Hs = H / d[:, None] / d[None, :]
    lam, V = np.linalg.eigh(Hs)
    keep = lam > rcond * max(lam.max(), 1e-300)
    gs = V.T @ (g / d)
    return (V[:, keep] @ (gs[keep] / lam[keep])) / d


def noise_scale(residual: np.ndarray) -> np.ndarray:
    """(6,) channel weights' noise: one value for the three force channels and one for the three torque
    channels (the RMS over the axes of :func:`axis_noise`): a sensor's axes are alike, and equal weights
    within force and within torque keep the base fit's force residual that of the offline batch fit."""
    sigma = axis_noise(residual)
    return np.repeat([rms(sigma[:3]), rms(sigma[3:])], 3)


NOT_IDENTIFIABLE = 1e-4
"""An eigenvalue of the correlation-scaled information below this is a combination of parameters the data
do not determine (:meth:`Discrepancy.uncertainty`): its standard error is over 100× theirs one at a time."""


@dataclass
class Evidence:
    """How one candidate did on held-out data."""

    effect: str
    gain: float
    """relative reduction of the held-out weighted mean square (0.05 = 5 %)"""
    folds_improved: int
    folds: int
    t: float
    significant: bool
    params: np.ndarray | None = None

    wins_needed: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "heldout_gain": self.gain,
            "folds_improved": self.folds_improved,
            "folds": self.folds,
            "wins_needed": self.wins_needed,
            "t": self.t,
            "significant": self.significant,
        }


def sign_test_p(folds: int, wins: int) -> float:
    """One-sided sign test: the chance that a candidate explaining nothing wins ``wins`` or more of ``folds``."""
    return sum(math.comb(folds, k) for k in range(wins, folds + 1)) / 2.0**folds


def wins_needed(folds: int, share: float, max_p: float) -> int:
    """Folds a candidate must improve: at least ``share`` of them, and a sign test of at most ``max_p``.

    ``folds + 1`` when no result can pass (fewer than 5 folds at the default 5.5 %: 4 of 4 is 6.25 %).
    """
    need = math.ceil(share * folds - 1e-9)
    while need <= folds and sign_test_p(folds, need) > max_p:
        need += 1
    return need


# --------------------------------------------------------------------------- the workflow


@dataclass
class State:
    """One model with its fit: what a step table row and a plot need."""

    label: str
    model: Model
    theta: np.ndarray
    residual: np.ndarray = None  # (n, 6) on every row, filled by the workflow
    weight_S: np.ndarray = None  # (n, 3) predicted weight in S


class Discrepancy:
    """The workflow on one recording stream and the motion derived from it (``run()`` does it all; see the
    module docstring)."""

    def __init__(
        self,
        stream: Stream,
        registry: Registry | None = None,
        settings: Settings | None = None,
        progress: Callable[[str], None] | None = None,
    ):
        self.registry = registry if registry is not None else Registry()
        self.settings = settings if settings is not None else Settings()
        self.say = progress or (lambda message: None)
        self.stream = stream
        self.motion, notes = recorded_motion(stream, self.settings.time_base, self.settings.derivative_window_s)
        self.notes = stream.notes + notes
        """what the user should know about the input"""
        self.y = np.concatenate([stream.samples.force_S, stream.samples.torque_S], axis=1)
        """(n, 6) measured force (N) and torque (N·m) in S"""
        self.usable = stream.samples.usable
        """(n,) rows with a finite wrench, good status and a fresh orientation"""
        n = len(self.y)
        usable_rows = np.flatnonzero(self.usable)
        stride = max(1, math.ceil(len(usable_rows) / self.settings.max_fit_samples))
        self.fit_rows = usable_rows[::stride]
        self.stride = stride
        self.fit_motion = self.motion.subset(self.fit_rows)
        self.y_fit = self.y[self.fit_rows]
        self.kept = self.usable.copy()  # the gate, over every row
        self.gate_fallback = False  # a gate would have set aside half the data and was not applied
        self.weights = np.ones(6)
        self.n = n

    # ------------------------------------------------------------------ fitting

    def _predict_all(self, model: Model, theta: np.ndarray) -> np.ndarray:
        return model.predict6(self.motion, theta)

    def force_block(self, model: Model, J: np.ndarray) -> np.ndarray:
        """(p,) True for the parameters fitted from the force channels, False for the torque's.

        The base model's weight and force bias come from the forces, its centre
        of mass and torque bias from the torques (as in the paper's cascade
        and the offline batch fit, so the base fit's force residual is the
        batch fit's); an effect parameter that moves the predicted force is
        fitted from the forces, one that moves only the torque from the torques.
        """
        rows = self.kept[self.fit_rows]
        Jw = J[rows] * self.weights[None, :, None]
        force_norm = np.sqrt(np.sum(Jw[:, :3] ** 2, axis=(0, 1)))
        torque_norm = np.sqrt(np.sum(Jw[:, 3:] ** 2, axis=(0, 1)))
        force = force_norm > 1e-6 * (force_norm + torque_norm)
        force[:6], force[6:12] = True, False
        return force

    @staticmethod
    def block_solve(HF, gF, HT, gT, force: np.ndarray) -> np.ndarray:
        """The force block from the force channels' normal equations, then the torque block from the torques'."""
        f, t = np.flatnonzero(force), np.flatnonzero(~force)
        delta = np.zeros(len(force))
        delta[f] = solve_scaled(HF[np.ix_(f, f)], gF[f])
        delta[t] = solve_scaled(HT[np.ix_(t, t)], gT[t] - HT[np.ix_(t, f)] @ delta[f])
        return delta

    def _normal(self, J: np.ndarray, r: np.ndarray):
        """Force-channel and torque-channel normal equations ``(HF, gF, HT, gT)`` of weighted J (m, 6, p), r (m, 6)."""
        p = J.shape[2]
        JF, JT = J[:, :3].reshape(-1, p), J[:, 3:].reshape(-1, p)
        return JF.T @ JF, JF.T @ r[:, :3].reshape(-1), JT.T @ JT, JT.T @ r[:, 3:].reshape(-1)

    def gauss_newton(
        self, model: Model, theta: np.ndarray, J: np.ndarray | None = None, max_iter: int = 8
    ) -> np.ndarray:
        """Weighted least squares of ``model`` on the kept fit rows, from ``theta`` (force block, then torque).

        Step control follows the cascade: the force block's step is halved
        until the force channels' cost does not rise, then the torque block's
        until the torque channels' cost (with the new force parameters) does
        not rise; a block whose step never helps is left where it is. So every
        accepted iterate is at least as good as the one before, in that order,
        and the last one is the best.
        """
        rows = self.kept[self.fit_rows]
        w = self.weights
        y = self.y_fit[rows]

        def costs_of(th):
            r = (y - model.predict6(self.fit_motion, th)[rows]) * w
            return r, np.array([np.sum(r[:, :3] ** 2), np.sum(r[:, 3:] ** 2)])

        r, costs = costs_of(theta)
        force = None
        tol = 1e-12
        for _ in range(max_iter):
            if J is None:
                J = model.jacobian(self.fit_motion, theta)
            if force is None:
                force = self.force_block(model, J)
            Jw = J[rows] * w[None, :, None]
            delta = self.block_solve(*self._normal(Jw, r), force)
            J = None
            start = costs
            # the force block's step must not raise the force channels' cost; then the torque
            # block's, given the force block's, must not raise the torque channels' cost
            for channel, step in ((0, np.where(force, delta, 0.0)), (1, np.where(force, 0.0, delta))):
                for _ in range(8):  # halve the step until it does not make its channel worse
                    if not step.any():
                        break
                    r_new, new = costs_of(theta + step)
                    if new[channel] <= costs[channel] * (1 + tol):
                        theta, r, costs = theta + step, r_new, new
                        break
                    step = step / 2
            change = np.abs(start - costs) / np.maximum(start, 1e-300)
            if change.max() < 1e-8:
                break
        return theta

    def uncertainty(self, model: Model, theta: np.ndarray) -> dict[str, Any]:
        """Each parameter's standard error, and the combinations the data cannot tell apart.

        The Gauss–Newton information of the final fit on the kept rows, block by block as it was fitted (the
        force block from the force channels, the torque block from the torques, given the force block),
        scaled to a correlation form C = D⁻¹HD⁻¹ (D = √diag H). A parameter's standard error is
        √((H⁻¹)ᵢᵢ · s²), s² the block's weighted residual mean square, times √stride when every k-th row was
        fitted (the other rows carry the same information); residuals taken as white (a coloured residual
        makes them optimistic). An eigenvector of C whose eigenvalue is below ``NOT_IDENTIFIABLE`` is a
        combination the motion does not determine: its standard error is over 100× what the parameters in it
        would have one at a time; it is reported with its largest components, and its parameters' errors
        as not identifiable (NaN) instead of a number from an inverse that does not exist.
        """
        rows = self.kept[self.fit_rows]
        J = model.jacobian(self.fit_motion, theta)
        force = self.force_block(model, J)
        Jw = J[rows] * self.weights[None, :, None]
        r = (self.y_fit[rows] - model.predict6(self.fit_motion, theta)[rows]) * self.weights
        HF, _, HT, _ = self._normal(Jw, r)
        std = np.full(len(theta), np.nan)
        combinations = []
        for block, H, res in ((force, HF, r[:, :3]), (~force, HT, r[:, 3:])):
            idx = np.flatnonzero(block)
            Hb = H[np.ix_(idx, idx)]
            d = np.sqrt(np.maximum(np.diag(Hb), 1e-300))
            lam, V = np.linalg.eigh(Hb / np.outer(d, d))
            s2 = float(np.sum(res**2)) / max(res.size - len(idx), 1) * self.stride
            good = lam >= NOT_IDENTIFIABLE
            cov = (V[:, good] / lam[good]) @ V[:, good].T  # the inverse on the identifiable directions
            block_std = np.sqrt(np.maximum(np.diag(cov), 0.0) * s2) / d
            lost = np.zeros(len(idx), dtype=bool)
            for k in np.flatnonzero(~good):
                v = V[:, k]
                major = np.flatnonzero(np.abs(v) >= 0.2)
                lost[major] = True
                combinations.append(
                    {
                        "parameters": [model.labels[idx[j]] for j in major],
                        "weights": [float(v[j] / np.abs(v[major]).max()) for j in major],
                        "eigenvalue": float(lam[k]),
                    }
                )
            block_std[lost] = np.nan
            std[idx] = block_std
        return {"std": {label: float(v) for label, v in zip(model.labels, std)}, "not_identifiable": combinations}

    def gate(self, model: Model, theta: np.ndarray) -> np.ndarray:
        """Rows kept after the contact gate on the residual of ``model`` (over every usable row)."""
        s = self.settings
        z = (self.y - self._predict_all(model, theta)) * self.weights
        use = self.usable
        zu = z[use]
        med = np.median(zu, axis=0)
        scale = 1.4826 * np.median(np.abs(zu - med), axis=0)
        scale = np.maximum(scale, 1e-12)
        bad = np.zeros(self.n, dtype=bool)
        bad[use] = np.any(np.abs(zu - med) > s.gate_sigmas * scale, axis=1)
        if bad.any() and self.motion.time_base == "seconds" and s.gate_dilate_s > 0:
            t = self.motion.t
            bad_t = t[bad]
            k = np.searchsorted(bad_t, t)
            near_next = np.abs(bad_t[np.minimum(k, len(bad_t) - 1)] - t)
            near_prev = np.abs(t - bad_t[np.maximum(k - 1, 0)])
            bad = np.minimum(near_next, near_prev) <= s.gate_dilate_s
        kept = use & ~bad
        if kept.sum() < 0.5 * use.sum():  # a gate that drops half the data is not gating contact (flagged)
            self.gate_fallback = True
            return use.copy()
        return kept

    def robust_start(self, model: Model, theta: np.ndarray, max_steps: int = 20) -> np.ndarray:
        """Trimmed least squares of ``model`` from ``theta``: the fit on the rows that fit it best.

        Concentration steps (as in FAST-LTS): fit on the ``trim_share`` of the
        usable rows with the smallest noise-weighted residual norm, recompute the
        residual on every row, pick the best share again, until the choice
        settles. Contact over anything less than the untrimmed share cannot
        pull this fit; ``fit`` then grows the rows back with the contact gate.
        A long contact along one direction in B would otherwise be absorbed into
        the weight and swell the gate's MAD so nothing is set aside.
        """
        use = self.usable
        previous = None
        for _ in range(max_steps):
            z = (self.y - self._predict_all(model, theta)) * self.weights
            d2 = np.sum(z**2, axis=1)
            cut = np.quantile(d2[use], self.settings.trim_share)
            kept = use & (d2 <= cut)
            # settled: the choice changes by less than 0.1 % of the rows (noise at the cut's border)
            if previous is not None and np.sum(kept != previous) <= 1e-3 * use.sum():
                break
            previous = kept
            self.kept = kept
            if self.kept[self.fit_rows].sum() < 20:
                break
            theta = self.gauss_newton(model, theta, max_iter=3)
        self.kept = self.gate(model, theta)
        return theta

    def fit(self, model: Model, theta: np.ndarray, J: np.ndarray | None = None) -> np.ndarray:
        """Fit, gate, refit until the gate settles (four gates at most; the last fit is on the last gate)."""
        for _ in range(4):
            theta = self.gauss_newton(model, theta, J)
            J = None
            kept = self.gate(model, theta)
            if np.array_equal(kept, self.kept):
                return theta
            self.kept = kept
        return self.gauss_newton(model, theta)

    # ------------------------------------------------------------------ candidates

    def _chunks(self) -> tuple[np.ndarray, int]:
        """Chunk id (0 .. 5K−1) of each kept fit row in time order (−1: gated), and the number of folds K.

        The chunks split the rows the gate kept, so a long stretch of contact
        does not leave folds empty (an empty fold cannot improve).
        """
        kept = self.kept[self.fit_rows]
        m = int(kept.sum())
        s = self.settings
        folds = int(min(s.folds, max(min(s.min_folds, s.folds), m // 20)))
        chunks = 5 * folds
        chunk = np.full(len(kept), -1)
        chunk[kept] = (np.arange(m) * chunks) // max(m, 1)
        return chunk, folds

    def test_candidates(
        self, model: Model, theta: np.ndarray, candidates: list[tuple[str, Effect]]
    ) -> tuple[list[Evidence], dict]:
        """Blocked cross-validation of each candidate added to ``model`` (linearised at ``theta``)."""
        s = self.settings
        rows = self.kept[self.fit_rows]
        r = (self.y_fit - model.predict6(self.fit_motion, theta)) * self.weights
        located = [effect for _, effect in candidates if isinstance(effect, LocatesItself)]
        if located:  # an instant or a time constant: set from what the model leaves, before initial() is read
            motion = self.fit_motion.subset(rows)
            weight_S = model.weight_S(motion, theta)
            for effect in located:
                effect.locate(motion, r[rows], weight_S)
        full = Model(model.effects + candidates)
        theta_full = full.initial(theta[:12])
        theta_full[: model.size] = theta
        J = full.jacobian(self.fit_motion, theta_full)
        force = self.force_block(full, J)
        Jw = J * self.weights[None, :, None]
        chunk, folds = self._chunks()
        nch = 5 * folds
        p = full.size
        HF, HT = np.zeros((nch, p, p)), np.zeros((nch, p, p))
        gF, gT = np.zeros((nch, p)), np.zeros((nch, p))
        ss = np.zeros(nch)
        for c in range(nch):
            sel = (chunk == c) & rows
            HF[c], gF[c], HT[c], gT[c] = self._normal(Jw[sel], r[sel])
            ss[c] = np.sum(r[sel] ** 2)
        base_cols = np.arange(model.size)

        def solve(chunks: np.ndarray, cols: np.ndarray) -> np.ndarray:
            pick = lambda M: M[chunks].sum(0)[np.ix_(cols, cols)]  # noqa: E731
            return self.block_solve(pick(HF), gF[chunks].sum(0)[cols], pick(HT), gT[chunks].sum(0)[cols], force[cols])

        def heldout(cols: np.ndarray) -> np.ndarray:
            sse = np.zeros(folds)
            for f in range(folds):
                test = np.zeros(nch, dtype=bool)
                test[5 * f : 5 * f + 5] = True
                train = np.ones(nch, dtype=bool)
                train[max(0, 5 * f - 1) : 5 * f + 6] = False  # the fold and a buffer chunk either side
                delta = solve(train, cols)
                H = (HF[test] + HT[test]).sum(0)[np.ix_(cols, cols)]
                g = (gF[test] + gT[test]).sum(0)[cols]
                sse[f] = ss[test].sum() - 2 * delta @ g + delta @ H @ delta
            return sse

        without = heldout(base_cols)
        out: list[Evidence] = []
        everything = np.ones(nch, dtype=bool)
        for name, _ in candidates:
            sl = full.slices[name]
            cols = np.concatenate([base_cols, np.arange(sl.start, sl.stop)])
            with_ = heldout(cols)
            improvement = (without - with_) / np.maximum(without, 1e-300)
            gain = float((without.sum() - with_.sum()) / max(without.sum(), 1e-300))
            wins = int(np.sum(improvement > 0))
            sd = float(np.std(improvement, ddof=1)) if folds > 1 else 0.0
            tstat = (
                float(np.mean(improvement) / (sd / math.sqrt(folds)))
                if sd > 0
                else math.copysign(math.inf, float(np.mean(improvement)) or -1.0)
            )
            significant = gain >= s.min_gain and wins >= wins_needed(folds, s.min_fold_share, s.max_sign_p)
            # the all-data step: the candidate's parameters if named
            out.append(
                Evidence(
                    name,
                    gain,
                    wins,
                    folds,
                    tstat,
                    significant,
                    solve(everything, cols),
                    wins_needed(folds, s.min_fold_share, s.max_sign_p),
                )
            )
        return out, {"J": J, "full": full, "theta_full": theta_full}

    # ------------------------------------------------------------------ the loop

    def candidates(self) -> tuple[list[tuple[str, Effect]], list[dict[str, str]], list[str]]:
        """The effect plugins to test, those that cannot be tested here (with why), and their notes."""
        names = self.settings.effects if self.settings.effects is not None else self.registry.names("effect")
        testable, skipped, notes = [], [], []
        for name in names:
            effect = self.registry.create(
                "effect", name, self.settings.effect_options.get(name, {}), where=f"effects.{name}"
            )
            reason = effect.check(self.motion)
            if reason:
                skipped.append({"effect": name, "reason": reason})
                continue
            notes.extend(effect.notes(self.motion))
            testable.append((name, effect))
        return testable, skipped, notes

    def run(self) -> dict[str, Any]:
        """Everything: the JSON-ready result (``"_states"`` holds arrays for the plots)."""
        with single_threaded_blas():  # tall thin products: one thread is fastest and steady here
            return self._run()

    def _run(self) -> dict[str, Any]:
        use = self.usable
        self.say("identifying the base model")
        fit0 = batch_fit(self.y[use, :3], self.y[use, 3:], self.motion.R_EB[use])
        theta = np.concatenate([fit0["gravity_force_B"], fit0["bias_force_S"], fit0["cog_S"], fit0["bias_torque_S"]])
        model = Model()
        self.weights = 1.0 / noise_scale(np.concatenate([fit0["residual_force_S"], fit0["residual_torque_S"]], 1))
        theta = self.robust_start(model, theta)
        theta = self.fit(model, theta)
        # weights from the base model's own residual (once; fixed for every comparison after)
        self.weights = 1.0 / noise_scale((self.y - self._predict_all(model, theta))[self.kept])
        theta = self.fit(model, theta)
        states = [State("baseline", model, theta)]
        candidates, skipped, notes = self.candidates()
        rounds: list[list[dict[str, Any]]] = []
        steps: list[dict[str, Any]] = []
        while candidates:
            self.say(f"round {len(rounds) + 1}: testing {', '.join(n for n, _ in candidates)}")
            evidence, lin = self.test_candidates(model, theta, candidates)
            rounds.append([e.as_dict() for e in evidence])
            best = max((e for e in evidence if e.significant), key=lambda e: e.gain, default=None)
            if best is None:
                break
            name = best.effect
            effect = dict(candidates)[name]
            self.say(f"adding {name}; re-identifying")
            new_model = model.with_effect(name, effect)
            # start from the all-data linear step of the candidate test
            full, theta_full = lin["full"], lin["theta_full"]
            cols = np.concatenate([np.arange(model.size), np.arange(full.slices[name].start, full.slices[name].stop)])
            start = theta_full[cols] + best.params
            theta = self.fit(new_model, start)
            model = new_model
            candidates = [(n, e) for n, e in candidates if n != name]
            states.append(State(f"after {name}", model, theta))
            steps.append(
                {
                    "effect": name,
                    "action": "named",
                    "round": len(rounds),
                    "score": best.gain,
                    "evidence": best.as_dict(),
                }
            )
            model, theta = self.retest(model, theta, states, steps, len(rounds))
        model, theta = self.structure_test(model, theta, states, steps, len(rounds))
        self.say("scoring")
        return self._report(states, steps, rounds, skipped, notes)

    def retest(
        self, model: Model, theta: np.ndarray, states: list[State], steps: list[dict[str, Any]], round_: int
    ) -> tuple[Model, np.ndarray]:
        """Test again each effect named before the newest one, as a candidate to the model without it; drop
        (and re-identify without) those no longer significant: an effect that stood in for another, now named
        (a hysteresis first fitted as a time lag), does not stay named. A dropped effect is not tested again."""
        for name, effect in list(model.effects[:-1]):
            without = Model([(n, e) for n, e in model.effects if n != name])
            sl = model.slices[name]
            theta_without = np.concatenate([theta[: sl.start], theta[sl.stop :]])
            # a copy: an effect that locates itself (an instant) would be moved by the test
            (evidence,), _ = self.test_candidates(without, theta_without, [(name, copy.copy(effect))])
            if evidence.significant:
                continue
            self.say(f"dropping {name}: no longer significant beside the others; re-identifying")
            params = model.effect_params(theta, name)
            model, theta = without, self.fit(without, theta_without)
            states.append(State(f"{name} dropped", model, theta))
            steps.append(
                {
                    "effect": name,
                    "action": "dropped",
                    "round": round_,
                    "score": evidence.gain,
                    "evidence": evidence.as_dict(),
                    "_effect": effect,
                    "_params": params,
                }
            )
        return model, theta

    def structure_share(
        self, model: Model, theta: np.ndarray, name: str, predicted: np.ndarray, own_noise: np.ndarray
    ) -> float:
        """The share of the structure ``model`` would leave without the effect ``name`` that the effect removes,
        on the channels where it acts.

        Without it, the other parameters are re-fitted on the same rows; each channel's structure is its
        excess over the noise, mean((residual / own noise)²) − 1 (0 for white noise), counted as 0 with the
        effect where it is under the leftover threshold squared (:func:`leftover_threshold`: what white noise
        stays under, so a gap closed to the noise is closed), and the channels count by the size of the
        effect's own contribution there (its prediction with and without, in noise units, squared): an
        effect on the forces is judged on the forces, not on torques something else disturbs. ``predicted``
        is ``model``'s prediction at the kept fit rows, ``own_noise`` (6,) each channel's noise there.
        """
        rows = self.kept[self.fit_rows]
        sl = model.slices[name]
        without = Model([(n, e) for n, e in model.effects if n != name])
        theta_without = self.gauss_newton(without, np.concatenate([theta[: sl.start], theta[sl.stop :]]))
        bare = without.predict6(self.fit_motion, theta_without)[rows]
        y = self.y_fit[rows]
        floor = leftover_threshold(int(rows.sum())) ** 2  # under it, white noise: the channel's gap is closed
        ms_with = np.mean(((y - predicted) / own_noise) ** 2, axis=0)
        excess_with = np.where(ms_with > floor, ms_with - 1.0, 0.0)
        excess_without = np.maximum(np.mean(((y - bare) / own_noise) ** 2, axis=0) - 1.0, 0.0)
        footprint = np.mean(((predicted - bare) / own_noise) ** 2, axis=0)
        before = float(footprint @ excess_without)
        return float(footprint @ (excess_without - excess_with)) / before if before > 0 else 1.0

    def structure_test(
        self, model: Model, theta: np.ndarray, states: list[State], steps: list[dict[str, Any]], round_: int
    ) -> tuple[Model, np.ndarray]:
        """Keep a named effect only if it explains most of the structure it is credited with
        (:meth:`structure_share` at least ``min_structure_share``, 50 %). A significant held-out gain alone
        is not enough: a physical effect outside the library projects onto some library term (a cable's pull
        fitted as a negative inertial mass), which then gains on held-out data yet leaves most of the
        structure in place. The effect that explains the least goes first, then the rest are tested again;
        what is set aside is reported (``steps``, action "set_aside", with its share), not named."""
        min_share = self.settings.min_structure_share
        shares: dict[str, float] = {}
        while model.effects and min_share > 0:  # 0: no structure test
            rows = self.kept[self.fit_rows]
            predicted = model.predict6(self.fit_motion, theta)[rows]
            own_noise = axis_noise(self.y_fit[rows] - predicted)
            shares = {name: self.structure_share(model, theta, name, predicted, own_noise) for name, _ in model.effects}
            name = min(shares, key=shares.get)
            if shares[name] >= min_share:
                break
            self.say(f"setting {name} aside: it explains {100 * shares[name]:.0f} % of the structure it faces")
            effect = dict(model.effects)[name]
            params = model.effect_params(theta, name)
            without = Model([(n, e) for n, e in model.effects if n != name])
            sl = model.slices[name]
            model, theta = without, self.fit(without, np.concatenate([theta[: sl.start], theta[sl.stop :]]))
            states.append(State(f"{name} set aside", model, theta))
            evidence = next(step["evidence"] for step in reversed(steps) if step["effect"] == name)
            steps.append(
                {
                    "effect": name,
                    "action": "set_aside",
                    "round": round_,
                    "score": 0.0,
                    "structure_share": shares[name],
                    "evidence": evidence,
                    "_effect": effect,
                    "_params": params,
                }
            )
        named = dict(model.effects)
        for step in steps:
            if step["action"] == "named" and step["effect"] in shares and step["effect"] in named:
                step["structure_share"] = shares[step["effect"]]
        return model, theta

    # ------------------------------------------------------------------ the report

    def _report(self, states, steps, rounds, skipped, notes) -> dict[str, Any]:
        kept = self.kept
        for state in states:
            state.residual = self.y - self._predict_all(state.model, state.theta)
            state.weight_S = state.model.weight_S(self.motion, state.theta)
        rms_kept = [rms(s.residual[kept]) for s in states]
        rms_all = [rms(s.residual[self.usable]) for s in states]
        for i, step in enumerate(steps):
            if step["action"] != "named":  # dropped or set aside: what it was when it went
                effect, params = step.pop("_effect"), step.pop("_params")
            else:
                model, theta = states[i + 1].model, states[i + 1].theta
                effect = dict(model.effects)[step["effect"]]
                params = model.effect_params(theta, step["effect"])
            step.update(
                {
                    "params": effect.describe(params),
                    "summary": effect.summary(params),
                    "rms_force_before": rms_kept[i][:3].tolist(),
                    "rms_force_after": rms_kept[i + 1][:3].tolist(),
                    "rms_torque_before": rms_kept[i][3:].tolist(),
                    "rms_torque_after": rms_kept[i + 1][3:].tolist(),
                }
            )
        final = states[-1]
        use = self.usable
        batch_kept = batch_fit(self.y[kept, :3], self.y[kept, 3:], self.motion.R_EB[kept])
        batch_all = batch_fit(self.y[use, :3], self.y[use, 3:], self.motion.R_EB[use])
        named = [name for name, _ in final.model.effects]
        options: dict[str, Any] = {"effects": [name for name, effect in final.model.effects if effect.online]}
        final_params: dict[str, Any] = {
            "gravity_force_B": final.theta[0:3].tolist(),
            "bias_force_S": final.theta[3:6].tolist(),
            "cog_S": final.theta[6:9].tolist(),
            "bias_torque_S": final.theta[9:12].tolist(),
        }
        for name, effect in final.model.effects:
            params = final.model.effect_params(final.theta, name)
            options.update(effect.estimator_options(params))
            final_params[name] = effect.describe(params)
        noise = 1.0 / self.weights
        over = rms_kept[-1] / noise
        own_noise = axis_noise(final.residual[kept])
        over_own = rms_kept[-1] / own_noise
        threshold = leftover_threshold(int(kept.sum()))
        leftover = [AXES[k] for k in range(6) if over_own[k] > threshold]
        where = {
            a: where_left(
                self.motion.t[kept],
                final.residual[kept, AXES.index(a)],
                float(own_noise[AXES.index(a)]),
                final.weight_S[kept],
            )
            for a in leftover
        }
        warnings = {
            "gate_not_applied": bool(self.gate_fallback),
            "final_above_noise": bool(np.any(over > self.settings.warn_rms_over_noise)),
            "leftover": bool(leftover),
        }
        notes = list(notes)
        for step in steps:
            if step["action"] == "set_aside":
                notes.append(
                    f"{step['effect']} set aside: it gained {100 * step['evidence']['heldout_gain']:.1f} % on "
                    f"held-out data but explains only {100 * step['structure_share']:.0f} % of the structure the "
                    f"model leaves without it (at least {100 * self.settings.min_structure_share:.0f} % to be "
                    f"named): it stood in for something the library does not model ({step['summary']})"
                )
        for name, effect in final.model.effects:
            if not effect.online:
                notes.append(
                    f"{name} is not compensated online (the kalman estimator does not model it): the "
                    f"haptic rendering keeps it"
                )
        if warnings["gate_not_applied"]:
            notes.append(
                "the contact gate would have set aside half of the samples or more, so it was not applied: "
                "if the recording has that much contact every figure here is contaminated by it; "
                "cut the contact out of the file"
            )
        if warnings["final_above_noise"]:
            notes.append(
                f"the final RMS is {over[:3].max():.2f}x (force), {over[3:].max():.2f}x (torque) the noise estimate "
                f"(above {self.settings.warn_rms_over_noise:g}x): something the tested effects do not explain remains "
                f"(or contact the gate did not catch); see --plots"
            )
        uncertainty = self.uncertainty(final.model, final.theta)
        for combination in uncertainty["not_identifiable"]:
            terms = " ".join(
                f"{'−' if w < 0 else '+'} {abs(w):.2f}·{name}"
                for w, name in zip(combination["weights"], combination["parameters"])
            ).lstrip("+ ")
            notes.append(
                "not identifiable from this motion: "
                + " and ".join(combination["parameters"])
                + f" trade off ({terms} is not determined): their values are one of many that fit "
                f"as well, and their standard errors are given as NaN"
            )
        if leftover:
            notes.append(
                "something the tested effects do not explain is left on "
                + ", ".join(f"{a} ({over_own[AXES.index(a)]:.2f}x its own noise)" for a in leftover)
                + f" (threshold {threshold:.3f}x for {int(kept.sum())} samples)"
                + "".join(where_text(a, where[a], self.motion.time_base) for a in leftover)
                + "; see --plots"
            )
        folds = rounds[0][0]["folds"] if rounds and rounds[0] else None
        if folds is not None and rounds[0][0]["wins_needed"] > folds:
            notes.append(
                f"{len(self.fit_rows)} samples give {folds} folds: no result over so few folds passes "
                f"the sign test (p ≤ {100 * self.settings.max_sign_p:g} %), so nothing can be named"
            )
        return {
            "input": self.stream.name,
            "samples": int(self.n),
            "usable": int(use.sum()),
            "gated": int(use.sum() - kept.sum()),
            "fit_samples": int(len(self.fit_rows)),
            "time_base": self.motion.time_base,
            "rate_hz": self.motion.rate_hz,
            "noise_estimate": {"force_S": noise[:3].tolist(), "torque_S": noise[3:].tolist()},
            "final_rms_over_noise": {"force_S": over[:3].tolist(), "torque_S": over[3:].tolist()},
            "axis_noise": {"force_S": own_noise[:3].tolist(), "torque_S": own_noise[3:].tolist()},
            "leftover": {
                "axes": leftover,
                "threshold": threshold,
                "where": where,
                "rms_over_axis_noise": {"force_S": over_own[:3].tolist(), "torque_S": over_own[3:].tolist()},
            },
            "warnings": warnings,
            "baseline": {"rms_force_S": rms_kept[0][:3].tolist(), "rms_torque_S": rms_kept[0][3:].tolist()},
            "steps": steps,
            "final": {
                "rms_force_S": rms_kept[-1][:3].tolist(),
                "rms_torque_S": rms_kept[-1][3:].tolist(),
                "params": final_params,
                "uncertainty": uncertainty,
            },
            "effects": named,
            "estimator_options": options,
            "batch_fit": {
                "rms_force_S": rms(np.c_[batch_kept["residual_force_S"]]).tolist(),
                "rms_torque_S": rms(np.c_[batch_kept["residual_torque_S"]]).tolist(),
            },
            "all_usable_rows": {
                "final_rms_force_S": rms_all[-1][:3].tolist(),
                "final_rms_torque_S": rms_all[-1][3:].tolist(),
                "batch_rms_force_S": rms(batch_all["residual_force_S"]).tolist(),
                "batch_rms_torque_S": rms(batch_all["residual_torque_S"]).tolist(),
            },
            "rounds": rounds,
            "skipped": skipped,
            "notes": self.notes + notes,
            "settings": {k: v for k, v in vars(self.settings).items()},
            "_states": states,
            "_kept": kept,
        }


def discrepancy(
    source: str | Path | Stream,
    settings: Settings | None = None,
    registry: Registry | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Run the workflow on a stream or a file (CSV or MCAP); the JSON-ready result.

    Plus, for the plots: ``_stream`` (the input), ``_motion`` (the motion derived from it),
    ``_states`` (each model's residual) and ``_kept`` (the final gate).
    """
    settings = settings if settings is not None else Settings()
    stream = source if isinstance(source, Stream) else load_stream(source)
    with numerical_failures(stream.name, "the discrepancy workflow"):  # a LinAlgError is the file's: one line
        workflow = Discrepancy(stream, registry, settings, progress)
        return workflow.run() | {"_stream": stream, "_motion": workflow.motion}


def discrepancy_folder(
    folder: str | Path,
    settings: Settings | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
):
    """:func:`discrepancy` on every recording under ``folder``, in parallel (``offline.folders``); each
    outcome's value is that file's result as :func:`json_ready` gives it (no arrays: it crosses processes)."""
    from hapticlab.sessions.offline.folders import map_recordings, recordings_in

    task = functools.partial(_discrepancy_one, settings=settings or Settings())
    return map_recordings(
        task, recordings_in(folder), scheduler=scheduler, workers=workers, progress=progress, description="discrepancy"
    )


def _discrepancy_one(path: Path, settings: Settings) -> dict[str, Any]:
    """One file of :func:`discrepancy_folder` (in a worker process; the registry is the worker's own)."""
    return json_ready(discrepancy(path, settings))


def json_ready(result: dict[str, Any]) -> dict[str, Any]:
    """The result without its private arrays, NaN as null."""

    def clean(value):
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items() if not str(k).startswith("_")}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, np.generic):
            return clean(value.item())
        return value

    return clean(result)


def toml_snippet(options: dict[str, Any]) -> str:
    """The ``[estimator]`` table reproducing the named effects online, to paste into a session file."""

    def fmt(value):
        if isinstance(value, str):
            return f'"{value}"'
        if isinstance(value, (list, tuple)):
            return "[" + ", ".join(fmt(v) for v in value) + "]"
        if isinstance(value, float):
            return f"{value:.6g}"
        return str(value)

    lines = ["[estimator]", 'name = "kalman"']
    lines += [f"{key} = {fmt(value)}" for key, value in options.items()]
    return "\n".join(lines)
