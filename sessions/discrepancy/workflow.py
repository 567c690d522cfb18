"""``hapticlab discrepancy``: where simulation and measurement disagree, which effect is missing, and the gap shrinking.

On a measured recording (CSV import contract or MCAP), the loop that names
effects; each step has its own module:

1. **Identify and simulate** (:mod:`~hapticlab.sessions.discrepancy.identify`).
   The base model (the paper's, with the weight's moment from the predicted
   weight) is fitted by weighted least squares, started robustly, and the
   sensor is simulated along the recorded motion with it.
2. **Gate contact** (``identify`` too). Samples far off on any channel are set
   aside; fit and gate are iterated until the gate settles, and again after
   every step. A gate that would set aside half of the samples is not applied,
   and the result says so (``warnings.gate_not_applied`` and a note), as it
   does when the final RMS stays above ``warn_rms_over_noise`` (1.5) times the
   noise estimate.
3. **Test every candidate effect** (the ``effect`` plugins not yet added)
   against the residual on held-out data
   (:mod:`~hapticlab.sessions.discrepancy.heldout`: blocked cross-validation
   over time and a sign test over the folds).
4. **Name** the candidate that best explains the held-out residual, if it is
   significant. Add it, re-identify everything, re-gate, test every effect
   named before again beside it (dropped when no longer significant), repeat
   until no candidate is significant.
5. **The structure test**: a named effect must explain at least
   ``min_structure_share`` (50 %) of the structure (each channel's excess over
   its own noise) the model leaves without it, or it is set aside, reported,
   not named: an effect outside the library gains on held-out data as some
   library term that leaves most of the structure in place.
6. **Show the gap shrink** (:mod:`~hapticlab.sessions.discrepancy.report`):
   RMS per axis before and after each step (every figure on the final gate's
   samples), against the offline batch fit, plots, and JSON (``DESIGN.md``)
   with the ``kalman`` options that reproduce the named effects online.

Large recordings are fitted and tested on at most ``max_fit_samples``
samples (every k-th, evenly spread); the RMS figures use every sample, by
blocks of rows (:mod:`~hapticlab.sessions.discrepancy.blocks`).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.host.registry import Registry
from hapticlab.core.sensor_model import Effect, Model
from hapticlab.sessions.discrepancy.blas import single_threaded_blas
from hapticlab.sessions.discrepancy.blocks import batch_fit_rows
from hapticlab.sessions.discrepancy.heldout import Evidence, cross_validate
from hapticlab.sessions.discrepancy.identify import Identification, noise_scale
from hapticlab.sessions.discrepancy.leftover import axis_noise, leftover_threshold
from hapticlab.sessions.discrepancy.ramp import PayloadRamp
from hapticlab.sessions.discrepancy.report import State, json_ready, report
from hapticlab.sessions.discrepancy.settings import Settings
from hapticlab.sessions.discrepancy.skew import ClockSkew
from hapticlab.sessions.offline.numerics import numerical_failures
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.stream import Stream

SKEW = "clock_skew"
"""The workflow's own candidate refining ``time_lag`` (:mod:`hapticlab.sessions.discrepancy.skew`)."""
REFINEMENTS: dict[str, tuple[str, type[Effect]]] = {
    SKEW: ("time_lag", ClockSkew),
    "payload_ramp": ("payload_change", PayloadRamp),
}
"""The workflow's own candidates, each refining a library effect (:mod:`.skew`, :mod:`.ramp`): name → (the
effect it refines, its class)."""


class Discrepancy(Identification):
    """The workflow on one recording stream and the motion derived from it (``run()`` does it all; see the
    module docstring): the identification, with the effect plugins to test and the loop that names them."""

    def __init__(
        self,
        stream: Stream,
        registry: Registry | None = None,
        settings: Settings | None = None,
        progress: Callable[[str], None] | None = None,
    ):
        super().__init__(stream, settings)
        self.registry = registry if registry is not None else Registry()
        self.say = progress or (lambda message: None)

    def candidates(self) -> tuple[list[tuple[str, Effect]], list[dict[str, str]], list[str]]:
        """The effect plugins to test, those that cannot be tested here (with why), and their notes; beside an
        effect the workflow refines, its refinement (:data:`REFINEMENTS`: ``clock_skew``, ``payload_ramp``)."""
        names = self.settings.effects if self.settings.effects is not None else self.registry.names("effect")
        registered = self.registry.names("effect")
        for name, (base, _) in REFINEMENTS.items():
            if base in names and name not in names and name not in registered:
                names = [*names, name]
        testable, skipped, notes = [], [], []
        for name in names:
            options = self.settings.effect_options.get(name, {})
            if name in REFINEMENTS and name not in registered:
                effect: Effect = REFINEMENTS[name][1](**options)
            else:
                effect = self.registry.create("effect", name, options, where=f"effects.{name}")
            reason = effect.check(self.motion)
            if reason:
                skipped.append({"effect": name, "reason": reason})
                continue
            notes.extend(effect.notes(self.motion))
            testable.append((name, effect))
        return testable, skipped, notes

    def eligible(self, evidence: Evidence, round_: list[Evidence], model: Model) -> bool:
        """Whether a significant candidate may be named. A refinement (``clock_skew`` of ``time_lag``,
        ``payload_ramp`` of ``payload_change``): beside a model with the effect it refines, its test is nested
        (what it adds must be significant); beside a model without it, it must beat that effect on held-out
        data, fold by fold, as a candidate must beat the model (a larger gain, in ``wins_needed`` of the
        folds), else the simpler effect is the answer and is not replaced by chance; its ``note`` says why not."""
        if evidence.effect not in REFINEMENTS:
            return True
        base = REFINEMENTS[evidence.effect][0]
        if base in dict(model.effects):
            return True
        rival = next((e for e in round_ if e.effect == base), None)
        if rival is None or evidence.fold_error is None or rival.fold_error is None:
            return True
        wins = int(np.sum(evidence.fold_error < rival.fold_error))
        if evidence.gain > rival.gain and wins >= evidence.wins_needed:
            return True
        evidence.note = (
            f"not named: it beats {base} ({100 * rival.gain:.2f} %) in {wins} of {evidence.folds} folds "
            f"({evidence.wins_needed} needed)"
        )
        return False

    def run(self) -> dict[str, Any]:
        """Everything: the JSON-ready result (``"_states"`` holds arrays for the plots)."""
        with single_threaded_blas():  # tall thin products: one thread is fastest and steady here
            return self._run()

    def _run(self) -> dict[str, Any]:
        use = self.usable
        self.say("identifying the base model")
        fit0 = self.batch_usable = batch_fit_rows(self.y[:, :3], self.y[:, 3:], self.motion.R_EB, use)
        theta = np.concatenate([fit0["gravity_force_B"], fit0["bias_force_S"], fit0["cog_S"], fit0["bias_torque_S"]])
        model = Model()
        residual0 = np.concatenate([fit0["residual_force_S"], fit0["residual_torque_S"]], 1)
        self.weights = 1.0 / noise_scale(residual0, self.steps, self.y[use] - residual0, self.motion.rate_hz)
        theta = self.robust_start(model, theta)
        theta = self.fit(model, theta)
        # weights from the base model's own residual (once; fixed for every comparison after)
        predicted = self.predict_all(model, theta)[self.kept]
        self.weights = 1.0 / noise_scale(self.y[self.kept] - predicted, self.steps, predicted, self.motion.rate_hz)
        theta = self.fit(model, theta)
        states = [State("baseline", model, theta)]
        candidates, skipped, notes = self.candidates()
        rounds: list[list[dict[str, Any]]] = []
        steps: list[dict[str, Any]] = []
        while candidates:
            self.say(f"round {len(rounds) + 1}: testing {', '.join(n for n, _ in candidates)}")
            evidence, lin = cross_validate(self, model, theta, candidates)
            best = max(
                (e for e in evidence if e.significant and self.eligible(e, evidence, model)),
                key=lambda e: e.gain,
                default=None,
            )
            rounds.append([e.as_dict() for e in evidence])
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
        return report(self, states, steps, rounds, skipped, notes)

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
            (evidence,), _ = cross_validate(self, without, theta_without, [(name, copy.copy(effect))])
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
            rate = self.motion.rate_hz / self.stride if self.motion.rate_hz else None  # every stride-th row
            own_noise = axis_noise(self.y_fit[rows] - predicted, self.steps, predicted, rate)
            shares = {name: self.structure_share(model, theta, name, predicted, own_noise) for name, _ in model.effects}
            name = min(shares, key=shares.__getitem__)
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
