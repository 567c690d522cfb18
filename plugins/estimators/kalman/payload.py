"""A payload change told from a contact: the test ``kalman`` runs on the force stage's refusal runs.

While the force stage refuses, its state does not move (only P grows), so the refused residual
e_k = y_k − R_SB,k·g − b is taken at the state each refused sample saw. A payload change (a mass hung
on the tool) adds Δg along gravity in B:

    e_k = R_SB,k·Δg + v_k,   Δg = mean(R_SB,kᵀ e_k)   (R_SB,k orthonormal: the least squares)

and the fit's residual is at the noise level. A contact with a ramp, a force fixed in S, or one along
another direction leaves a larger residual or a Δg off the vertical. A payload is a step, so the run's
onset (its first samples, accepted or refused) already carries the whole change; a contact that ramps up
begins its run where the ramp crosses the gate, at a fraction of its plateau (``ONSET_SHARE``). Without
that test a light contact's plateau passed the fit once the window had grown past its ramp (the fit's
residual is in units of the noise estimate, which the ramp's accepted part had raised).
:class:`PayloadWatch` follows the runs sample by sample and tests a run once it is ``change_ns`` long
(docs/estimators.md, "Payload change"); the estimator re-opens gravity and replays the window when the
test passes.

Symbols and shapes (m samples): e (m, 3) N; A = R_SB (m, 3, 3); y (m, 3) the force stage's reading, N;
f (m, 3) force_S, N; tq (m, 3) torque_S, N·m; R (m, 3, 3) R_EB; r (3,) the force noise variances, N²;
g (3,) gravity_force_B, N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

WINDOW_RUNS = 3
"""The refused window tested is the run from its start, at most this many times the test's delay."""
FIT_RATIO = 2.0
"""The gravity-change fit must leave a mean squared residual below this many noise variances."""
MAX_TILT = 0.25
"""rad: the fitted weight change must be along the identified weight (gravity) within this angle."""
RUN_BREAK = 10
"""This many consecutive accepted samples end a refusal run (isolated ones do not)."""
MIN_SAMPLES = 10
"""The fewest refused samples a test is made on."""
ONSET_FRACTION = 0.1
"""The run's onset: the samples the force stage was given within this fraction of the test's delay
(``change_ns``; 30 ms by default) of the run's first refused one, accepted ones too (near the gate the
refused ones alone are those the noise pushed up), and at least ``ONSET_SAMPLES``: the same samples
whatever the block size."""
ONSET_SAMPLES = 3
"""The fewest samples the onset is taken over (a 10 Hz sensor has one within 30 ms of the first). At such
rates the test is blind: a 0.4 s ramp is 4 samples, and the first refused one is near the top."""
MOVED_AGAINST_M = 0.0001
"""m: a weight change is no payload when the flange moved at least this far against it over the run: the tool
pressed into what pushes back (a touch: the force grows as the tool goes in, −k·Δx) or rose off what held it
(the force it gave vanishes). A payload hangs whatever the flange does; a fast touch at a held orientation
passes every other test (a step along gravity: teleoperation's palpation, 0.6 s presses at 3000 N/m)."""
ONSET_SHARE = 0.8
"""The onset's mean change along the fitted Δg must be at least this share of |Δg|. Measured at 1 kHz on a
random tour: see docs/estimators.md ("Payload change")."""


class RefusedWindow:
    """A refusal run's samples, field by field, in arrays that grow by doubling: appending a tick's samples
    costs their copy, not the window's (a list of per-tick parts concatenated at every test is quadratic
    in the run's length). Fields: e, A, y, f, tq, R
    (the module's symbols)."""

    SHAPES: ClassVar[dict[str, tuple[int, ...]]] = {
        "e": (3,),
        "A": (3, 3),
        "y": (3,),
        "f": (3,),
        "tq": (3,),
        "R": (3, 3),
    }

    def __init__(self, capacity: int = 256):
        self.n = 0
        self._data = {key: np.empty((capacity, *shape)) for key, shape in self.SHAPES.items()}
        # the fit's sums over the first ``_summed`` samples: Σ Aᵀe (3,), Σ e² (3,), Σ e_i A_ij (3, 3),
        # Σ A_ij A_il (3, 3, 3)
        self._summed = 0
        self._Ae, self._ee = np.zeros(3), np.zeros(3)
        self._eA, self._AA = np.zeros((3, 3)), np.zeros((3, 3, 3))

    def __len__(self) -> int:
        return self.n

    def append(self, **parts: np.ndarray) -> None:
        m = len(parts["e"])
        if self.n + m > len(self._data["e"]):
            capacity = max(2 * len(self._data["e"]), self.n + m)
            for key, old in self._data.items():
                new = np.empty((capacity, *old.shape[1:]))
                new[: self.n] = old[: self.n]
                self._data[key] = new
        for key, column in self._data.items():
            column[self.n : self.n + m] = parts[key]
        self.n += m

    def window(self) -> dict[str, np.ndarray]:
        """The samples so far, by field (views: valid until the next append)."""
        return {key: column[: self.n] for key, column in self._data.items()}

    def fit(self, r: np.ndarray) -> tuple[np.ndarray, float]:
        """The least squares of e_k = A_k·Δg over the samples so far (A_k orthonormal, so Δg = mean(A_kᵀ e_k)):
        (Δg (3,), N; the mean squared residual per axis in units of ``r``, the noise variances (3,), N²).
        From running sums, each sample added once: O(1) a tick, not O(window)."""
        new = slice(self._summed, self.n)
        e, A = self._data["e"][new], self._data["A"][new]
        self._Ae += np.einsum("kji,kj->i", A, e)
        self._ee += np.einsum("ki,ki->i", e, e)
        self._eA += np.einsum("ki,kij->ij", e, A)
        self._AA += np.einsum("kij,kil->ijl", A, A)
        self._summed = self.n
        dg = self._Ae / self.n
        squares = self._ee - 2.0 * (self._eA @ dg) + np.einsum("ijl,j,l->i", self._AA, dg, dg)
        return dg, float(np.mean(squares / r)) / self.n


@dataclass(frozen=True)
class PayloadChange:
    """A refusal run the test found to be a payload change."""

    t_ns: int
    """The newest sample's time, ns."""
    weight_change: float
    """|Δg|, N."""
    run_s: float
    """How long the run had lasted, s."""
    window: dict[str, np.ndarray]
    """The run's refused samples (RefusedWindow fields), for the estimator to replay."""


class PayloadWatch:
    """The force stage's refusal runs, followed block by block; each run tested once it is ``change_ns`` long,
    at every block until its whole window (``WINDOW_RUNS``·``change_ns`` from its first refused sample) was
    seen."""

    def __init__(self, change_ns: int):
        self.change_ns = change_ns
        self._end_run()

    def _end_run(self) -> None:
        """No run: what the next one starts from."""
        self.since: int | None = None  # t_ns of the run's first refused sample (None: no run)
        self._p_start: np.ndarray | None = None  # the flange there, m in B (None: not known)
        self.window = RefusedWindow()
        self._accepted = 0  # consecutive accepted samples (a run survives a few)
        self._tested_full = False  # the run's whole window was tested (negative)
        self._onset, self._onset_n = np.zeros(3), 0  # the onset's sum of A_kᵀe_k (N, in B) and its samples
        self._onset_done = False  # the onset is complete (nothing more to add to it in this run)

    @property
    def in_run(self) -> bool:
        return self.since is not None

    def onset_share(self, dg: np.ndarray) -> float:
        """The run's onset (``ONSET_FRACTION``): the mean of its samples' own changes A_kᵀe_k along ``dg``
        (3,), as a share of |dg| (1 for a step; a ramp's onset less; NaN before any sample)."""
        if self._onset_n == 0:
            return math.nan
        return float(self._onset @ dg) / self._onset_n / float(dg @ dg)

    def observe(
        self,
        t_ns: np.ndarray,
        gated: np.ndarray,
        usable: np.ndarray,
        e: np.ndarray,
        A: np.ndarray,
        y: np.ndarray,
        f: np.ndarray,
        tq: np.ndarray,
        R: np.ndarray,
        r: np.ndarray,
        g: np.ndarray,
        p: np.ndarray | None = None,
    ) -> PayloadChange | None:
        """One block's samples (``gated``: refused by the force stage; ``usable``: given to it; ``p``: the
        flange's positions, m in B, or None): the payload change found, None otherwise. After a change the run
        ends (the estimator has re-opened gravity)."""
        start: int | np.intp = 0
        for k in np.flatnonzero(usable):
            if gated[k]:
                if self.since is None:  # (its window and onset were left empty by _end_run)
                    self.since = int(t_ns[k])
                    self._p_start = None if p is None or not len(p) else p[k].copy()
                    start = k
                self._accepted = 0
            elif self.since is not None:
                self._accepted += 1
                if self._accepted >= RUN_BREAK:
                    self._end_run()
                    start = k + 1
        if self.since is None:
            return None
        if not self._onset_done:  # (a tick in a long run costs nothing more once its onset is complete)
            onset_ns = ONSET_FRACTION * self.change_ns
            for k in np.flatnonzero(usable[start:]) + start:  # the onset: accepted samples count too
                if self._onset_n >= ONSET_SAMPLES and t_ns[k] - self.since > onset_ns:
                    self._onset_done = True
                    break
                self._onset += A[k].T @ e[k]  # the sample's own Δg, in B
                self._onset_n += 1
        # the window is the run from its first refused sample on (its onset included: a contact
        # ramps up, a payload is a step), at most WINDOW_RUNS·change_ns long
        newest = self.since + WINDOW_RUNS * self.change_ns
        keep = np.zeros(len(t_ns), dtype=bool)
        keep[start:] = gated[start:] & (t_ns[start:] <= newest)
        if keep.any():
            self.window.append(e=e[keep], A=A[keep], y=y[keep], f=f[keep], tq=tq[keep], R=R[keep])
        t_last = int(t_ns[-1])
        if t_last - self.since < self.change_ns or not self.window or self._tested_full:
            return None
        self._tested_full = t_last >= newest  # the whole window seen: no further test in this run
        if len(self.window) < MIN_SAMPLES:
            return None
        dg, ratio = self.window.fit(r)
        gn, dn = float(np.linalg.norm(g)), float(np.linalg.norm(dg))
        vertical = gn > 0 and dn > 0 and abs(float(g @ dg)) >= math.cos(MAX_TILT) * gn * dn
        if not (ratio < FIT_RATIO and vertical):
            return None
        if not self.onset_share(dg) >= ONSET_SHARE:
            return None  # a ramp: the run began below its plateau
        if self._p_start is not None and p is not None and len(p):
            moved = p[int(np.flatnonzero(usable)[-1]) if usable.any() else -1] - self._p_start
            if -float(moved @ dg) / dn >= MOVED_AGAINST_M:
                return None  # a touch: the flange went into what pushes back, or off what held it
        change = PayloadChange(t_last, dn, (t_last - self.since) * 1e-9, self.window.window())
        self._end_run()
        return change
