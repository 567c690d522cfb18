"""Testing candidate effects on held-out data: blocked cross-validation over time and the sign test.

Each candidate (an ``effect`` plugin not yet added) is tested against the
residual of the current model: ``folds`` contiguous folds of the kept samples
(at least ``min_folds``, smaller ones on short recordings), each held out in
turn with a buffer of one fifth of a fold either side left out of its
training set (residuals are correlated in time). Model and model-plus-candidate
are both re-fitted on the training folds (one Gauss–Newton step from the
current fit) and scored on the held-out fold.

A candidate is significant when it lowers the held-out mean square
(noise-weighted) by at least ``min_gain`` summed over the folds, and in at
least ``min_fold_share`` of the folds and in enough of them for a one-sided
sign test of at most ``max_sign_p`` (8 of 10, 5 of 5; below 5 folds nothing
passes). The t statistic over the folds is reported, not used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.sensor_model import Effect, LocatesItself, Model, Motion
from hapticlab.sessions.discrepancy.identify import Identification


@dataclass
class Evidence:
    """How one candidate did on held-out data."""

    effect: str
    gain: float
    """relative change of the held-out weighted mean square, (without − with) / max(without, with): a reduction
    is its share of the error without (0.05 = 5 %), a rise its share of the error with, so it lies in [−1, 1]
    whatever a candidate does on a fold it cannot predict (:func:`relative_gain`)"""
    folds_improved: int
    folds: int
    t: float
    """t statistic of the per-fold improvements (reported, not used)"""
    significant: bool
    params: np.ndarray | None = None
    """the candidate's parameter step from the all-data fit (the start of its re-identification if named)"""
    wins_needed: int = 0
    """folds it had to improve (:func:`wins_needed`)"""
    note: str = ""
    """why a candidate is not fitted ("" when it is): its fit on the other folds did not carry to a fold"""
    fold_error: np.ndarray | None = None
    """(folds,) the held-out weighted squared error on each fold with the candidate: to set two candidates
    against each other fold by fold (``Discrepancy.eligible``)"""

    def as_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "heldout_gain": self.gain,
            "folds_improved": self.folds_improved,
            "folds": self.folds,
            "wins_needed": self.wins_needed,
            "t": self.t,
            "significant": self.significant,
            **({"note": self.note} if self.note else {}),
        }


NOT_CARRIED = 10.0
"""A candidate not significant whose fit on the other folds leaves a held-out fold with this many times its error
without it is reported "not fitted" with that fold (a note: the decision is the fold rule's): the effect is
determined by that fold alone (a warm-up's settling over in the first fold,
which the later ones cannot say how large it was)."""


def relative_gain(without: np.ndarray | float, with_: np.ndarray | float) -> np.ndarray:
    """(without − with) / max(without, with), elementwise: a reduction's share of the error before, a rise's share
    of the error after, in [−1, 1] by construction (a ratio to ``without`` alone ran to −10²⁹ when a candidate's
    fit exploded on a fold), 0 where both are 0."""
    without, with_ = np.asarray(without, dtype=float), np.asarray(with_, dtype=float)
    return (without - with_) / np.maximum(np.maximum(without, with_), 1e-300)


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


def fold_chunks(fit: Identification) -> tuple[np.ndarray, int]:
    """Chunk id (0 .. 5K−1) of each kept fit row in time order (−1: gated), and the number of folds K.

    The chunks split the rows the gate kept, so a long stretch of contact
    does not leave folds empty (an empty fold cannot improve).
    """
    kept = fit.kept[fit.fit_rows]
    m = int(kept.sum())
    s = fit.settings
    folds = int(min(s.folds, max(min(s.min_folds, s.folds), m // 20)))
    chunks = 5 * folds
    chunk = np.full(len(kept), -1)
    chunk[kept] = (np.arange(m) * chunks) // max(m, 1)
    return chunk, folds


def candidate_jacobian(
    model: Model, candidates: list[tuple[str, Effect]], full: Model, motion: Motion, theta_full: np.ndarray
) -> np.ndarray:
    """(m, 6, p) ``full.jacobian(motion, theta_full)``, ``full`` being ``model`` and every candidate: the
    model's columns from ``model`` alone, each candidate's from ``model`` and that candidate alone.

    The same numbers: a candidate's parameters are at their switched-off ``initial()`` values in
    ``theta_full``, where an effect leaves the prediction unchanged, so the other candidates change nothing in
    a column that is not theirs. But each prediction runs one candidate instead of all of them: the cost of
    the candidate test grows with the number of candidates, not with its square.
    """
    J = np.empty((len(motion), 6, full.size))
    J[:, :, : model.size] = model.jacobian(motion, theta_full[: model.size])
    for name, effect in candidates:
        sl = full.slices[name]
        alone = model.with_effect(name, effect)
        theta = np.concatenate([theta_full[: model.size], theta_full[sl]])
        J[:, :, sl] = alone.jacobian(motion, theta, columns=slice(model.size, alone.size))
    return J


def cross_validate(
    fit: Identification, model: Model, theta: np.ndarray, candidates: list[tuple[str, Effect]]
) -> tuple[list[Evidence], dict]:
    """Blocked cross-validation of each candidate added to ``model`` (linearised at ``theta``)."""
    s = fit.settings
    rows = fit.kept[fit.fit_rows]
    r = (fit.y_fit - model.predict6(fit.fit_motion, theta)) * fit.weights
    located = [effect for _, effect in candidates if isinstance(effect, LocatesItself)]
    if located:  # an instant or a time constant: set from what the model leaves, before initial() is read
        motion = fit.fit_motion.subset(rows)
        weight_S = model.weight_S(motion, theta)
        for effect in located:
            effect.locate(motion, r[rows], weight_S)
    full = Model(model.effects + candidates)
    theta_full = full.initial(theta[:12])
    theta_full[: model.size] = theta
    J = candidate_jacobian(model, candidates, full, fit.fit_motion, theta_full)
    force = fit.force_block(full, J)
    J *= fit.weights[None, :, None]  # weighted in place: the (m, 6, p) array is the candidate test's largest
    Jw = J
    chunk, folds = fold_chunks(fit)
    nch = 5 * folds
    p = full.size
    HF, HT = np.zeros((nch, p, p)), np.zeros((nch, p, p))
    gF, gT = np.zeros((nch, p)), np.zeros((nch, p))
    ss = np.zeros(nch)
    for c in range(nch):
        sel = (chunk == c) & rows
        HF[c], gF[c], HT[c], gT[c] = fit.normal_equations(Jw[sel], r[sel])
        ss[c] = np.sum(r[sel] ** 2)
    base_cols = np.arange(model.size)

    def solve(chunks: np.ndarray, cols: np.ndarray) -> np.ndarray:
        pick = lambda M: M[chunks].sum(0)[np.ix_(cols, cols)]  # noqa: E731
        return fit.block_solve(pick(HF), gF[chunks].sum(0)[cols], pick(HT), gT[chunks].sum(0)[cols], force[cols])

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
        if not np.isfinite(with_).all():  # a singular step: nothing to score
            with_ = np.where(np.isfinite(with_), with_, np.inf)
        improvement = relative_gain(without, with_)
        gain = float(relative_gain(without.sum(), with_.sum()))
        worse = np.flatnonzero(with_ > NOT_CARRIED * np.maximum(without, 1e-300))
        note = (
            f"not fitted: its fit on the other folds does not carry to fold {int(worse[0]) + 1} of {folds} "
            f"({with_[worse[0]] / max(without[worse[0]], 1e-300):.3g}× the error there without it)"
            if len(worse)
            else ""
        )
        wins = int(np.sum(improvement > 0))
        sd = float(np.std(improvement, ddof=1)) if folds > 1 else 0.0
        tstat = (
            float(np.mean(improvement) / (sd / math.sqrt(folds)))
            if sd > 0
            else math.copysign(math.inf, float(np.mean(improvement)) or -1.0)
        )
        significant = gain >= s.min_gain and wins >= wins_needed(folds, s.min_fold_share, s.max_sign_p)
        note = "" if significant else note  # (a named effect's fold it cannot carry to is the fit's to tell)
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
                note,
                with_,
            )
        )
    return out, {"full": full, "theta_full": theta_full}
