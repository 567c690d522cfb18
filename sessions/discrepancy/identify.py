"""Identifying a model on one recording: weighted Gauss–Newton, the contact gate, the robust start, standard errors.

The base model (the paper's, with the weight's moment from the predicted
weight) and every model with effects added are fitted by weighted least
squares (Gauss–Newton, force block from the forces, then torque block from
the torques). The base model is started robustly: from the offline batch fit,
trimmed least squares (the half of the rows that fit best, re-chosen until it
settles), so contact over anything under half the recording cannot pull the
start. Each channel is weighted by its noise, estimated from the residual's
sample-to-sample differences (robust: MAD), so forces and torques count alike.

The contact gate sets aside samples whose residual is more than
``gate_sigmas`` robust standard deviations (MAD) off on any channel, with
``gate_dilate_s`` either side when ``t`` is a time; fit and gate are iterated
until the gate settles. A gate that would set aside half of the samples is
not applied (``gate_fallback``).

Large recordings are fitted on at most ``max_fit_samples`` samples (every
k-th, evenly spread).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hapticlab.core.errors import ConfigError
from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.core.parallel import column_median
from hapticlab.core.sensor_model import Model, Motion, motion_from_poses
from hapticlab.sessions.discrepancy.blocks import predict_rows
from hapticlab.sessions.discrepancy.leftover import axis_noise
from hapticlab.sessions.discrepancy.quality import channel_steps
from hapticlab.sessions.discrepancy.settings import Settings
from hapticlab.sessions.offline.metrics import rms
from hapticlab.sessions.recording.csvimport import CsvError
from hapticlab.sessions.recording.stream import Stream


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
    # contiguous float64 whatever the reader gave (columns of a wider table, another dtype): the analysis
    # does not depend on how the rows arrived
    t = np.ascontiguousarray(stream.t_s, dtype=float)
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
    quat = np.ascontiguousarray(quat, dtype=float)
    positions = None if samples.p_BoEo_B is None else np.ascontiguousarray(samples.p_BoEo_B, dtype=float)
    if positions is not None and not np.isfinite(positions).all():
        positions = None
    return motion_from_poses(t, quat, positions, base, window_s), notes


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


def noise_scale(
    residual: np.ndarray,
    steps: np.ndarray | None = None,
    predicted: np.ndarray | None = None,
    rate_hz: float | None = None,
) -> np.ndarray:
    """(6,) channel weights' noise: one value for the three force channels and one for the three torque
    channels (the RMS over the axes of :func:`axis_noise`, with its ``steps`` and ``predicted`` for quantised
    channels, ``rate_hz`` for coloured noise): a sensor's axes are alike, and equal weights within force and
    within torque keep the base fit's force residual that of the offline batch fit."""
    sigma = axis_noise(residual, steps, predicted, rate_hz)
    return np.repeat([rms(sigma[:3]), rms(sigma[3:])], 3)


NOT_IDENTIFIABLE = 1e-4
"""An eigenvalue of the correlation-scaled information below this is a combination of parameters the data
do not determine (:meth:`Identification.uncertainty`): its standard error is over 100× theirs one at a time."""


class Identification:
    """One recording stream, the motion derived from it, and the weighted fit of a model to them (the state
    the fit carries: the gate ``kept``, the channel ``weights``)."""

    def __init__(self, stream: Stream, settings: Settings | None = None):
        self.settings = settings if settings is not None else Settings()
        self.stream = stream
        self.motion, notes = recorded_motion(stream, self.settings.time_base, self.settings.derivative_window_s)
        self.notes = stream.notes + notes
        """what the user should know about the input"""
        self.y = np.concatenate([stream.samples.force_S, stream.samples.torque_S], axis=1, dtype=float)
        """(n, 6) measured force (N) and torque (N·m) in S"""
        self.usable = stream.samples.usable
        """(n,) rows with a finite wrench, good status and a fresh orientation"""
        self.steps = channel_steps(self.y[self.usable])
        """(6,) each channel's quantisation step (N, N·m; NaN where its values lie on no grid): the noise
        figures count the rounding (:func:`~hapticlab.sessions.discrepancy.quality.quantised_noise`)"""
        n = len(self.y)
        usable_rows = np.flatnonzero(self.usable)
        stride = max(1, math.ceil(len(usable_rows) / self.settings.max_fit_samples))
        self.fit_rows = usable_rows[::stride]
        """the usable rows fitted and tested on: every ``stride``-th, at most ``max_fit_samples``"""
        self.stride = stride
        self.fit_motion = self.motion.subset(self.fit_rows)
        self.y_fit = self.y[self.fit_rows]
        self.kept = self.usable.copy()
        """(n,) the contact gate, over every row"""
        self.gate_fallback = False
        """a gate would have set aside half the data and was not applied"""
        self.refused_gate: np.ndarray | None = None
        """(n,) the rows the last gate not applied would have kept (None: every gate was applied)"""
        self.weights = np.ones(6)
        """(6,) each channel's weight: 1 / its noise (1/N for forces, 1/(N·m) for torques)"""
        self.n = n
        self.batch_usable: dict[str, np.ndarray] | None = None
        """the offline batch fit on every usable row, once computed (the base model's start, and beside the
        report's RMS)"""

    def predict_all(self, model: Model, theta: np.ndarray) -> np.ndarray:
        """(n, 6) the wrench ``model`` predicts at every row with parameters ``theta`` (block by block)."""
        return predict_rows(model, self.motion, theta)

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

    def normal_equations(self, J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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
            delta = self.block_solve(*self.normal_equations(Jw, r), force)
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
        HF, _, HT, _ = self.normal_equations(Jw, r)
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
        z = (self.y - self.predict_all(model, theta)) * self.weights
        use = self.usable
        zu = z[use]
        med = column_median(zu)
        scale = 1.4826 * column_median(np.abs(zu - med))
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
            self.refused_gate = kept
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
            z = (self.y - self.predict_all(model, theta)) * self.weights
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
