"""The discrepancy workflow's result: RMS per axis before and after each step, notes, warnings, JSON and TOML.

Every RMS figure is on the final gate's samples (those under ``all_usable_rows``
on every usable row), beside the offline batch fit; what is left on each channel is set
against that channel's own noise (:mod:`hapticlab.sessions.discrepancy.leftover`).
The JSON follows the contract in ``DESIGN.md``; the ``[estimator]`` TOML table
reproduces the named effects online in ``kalman``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.sensor_model import Model
from hapticlab.sessions.discrepancy.blocks import batch_fit_rows, weight_rows
from hapticlab.sessions.discrepancy.gated import CONTACT_FREE_SHARE, set_aside, set_aside_notes
from hapticlab.sessions.discrepancy.identify import Identification
from hapticlab.sessions.discrepancy.leftover import (
    axis_noise,
    effective_samples,
    leftover_threshold,
    where_left,
    where_text,
)
from hapticlab.sessions.discrepancy.quality import data_quality, quality_notes
from hapticlab.sessions.offline.metrics import rms

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")


@dataclass
class State:
    """One model with its fit: what a step table row and a plot need."""

    label: str
    model: Model
    theta: np.ndarray
    fit: Identification | None = None
    """the recording the state was fitted on (set by :func:`report`): where ``residual`` and ``weight_S`` are
    computed each time they are read, so a result holds one model's (n, 6) arrays at a time, not every state's"""

    @property
    def residual(self) -> np.ndarray:
        """(n, 6) measured minus predicted wrench on every row, N and N·m."""
        assert self.fit is not None, "a State's arrays are computed once report() has set its fit"
        return self.fit.y - self.fit.predict_all(self.model, self.theta)

    @property
    def weight_S(self) -> np.ndarray:
        """(n, 3) the predicted weight in S on every row, N."""
        assert self.fit is not None, "a State's arrays are computed once report() has set its fit"
        return weight_rows(self.model, self.fit.motion, self.theta)


def report(
    fit: Identification,
    states: list[State],
    steps: list[dict[str, Any]],
    rounds: list[list[dict[str, Any]]],
    skipped: list[dict[str, str]],
    notes: list[str],
) -> dict[str, Any]:
    """The JSON-ready result of a finished workflow (``"_states"`` and ``"_kept"`` hold arrays for the plots).

    ``states``: the model after each step (the baseline first), ``steps`` one per step (effect named, dropped
    or set aside), ``rounds`` each round's evidence, ``skipped`` the effects that could not be tested, ``notes``
    the candidates' notes on the input.
    """
    # first, while no (n, 6) array of the report is held: the Jacobian's columns are predicted side by side
    uncertainty = fit.uncertainty(states[-1].model, states[-1].theta)
    kept = fit.kept
    rms_kept, rms_all = [], []
    for state in states:
        state.fit = fit
        residual = state.residual
        rms_kept.append(rms(residual[kept]))
        rms_all.append(rms(residual[fit.usable]))
    final = states[-1]
    final_residual, final_weight_S = residual, final.weight_S
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
    use = fit.usable
    batch_kept = batch_fit_rows(fit.y[:, :3], fit.y[:, 3:], fit.motion.R_EB, kept)
    batch_rms_kept = [rms(np.c_[batch_kept["residual_force_S"]]), rms(np.c_[batch_kept["residual_torque_S"]])]
    del batch_kept  # its (n, 6) residuals, not held through the rest of the report
    batch_all = fit.batch_usable
    if batch_all is None:
        batch_all = batch_fit_rows(fit.y[:, :3], fit.y[:, 3:], fit.motion.R_EB, use)
    batch_rms_all = [rms(batch_all["residual_force_S"]), rms(batch_all["residual_torque_S"])]
    del batch_all
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
    noise = 1.0 / fit.weights
    over = rms_kept[-1] / noise
    rate = fit.motion.rate_hz
    residual_kept = final_residual[kept]
    own_noise = axis_noise(residual_kept, fit.steps, fit.y[kept] - residual_kept, rate)
    over_own = rms_kept[-1] / own_noise
    independent = effective_samples(residual_kept, rate)  # the kept samples, or fewer for a coloured noise
    threshold = leftover_threshold(independent)
    leftover = [AXES[k] for k in range(6) if over_own[k] > threshold]
    where = {
        a: where_left(
            fit.motion.t[kept],
            final_residual[kept, AXES.index(a)],
            float(own_noise[AXES.index(a)]),
            final_weight_S[kept],
        )
        for a in leftover
    }
    del residual_kept
    quality = data_quality(fit.y, fit.motion.t, use, kept, own_noise, fit.y - final_residual)
    residual_use = final_residual[use]
    del final_residual, residual
    # a gate not applied (half the rows or more) is looked at as it would have been: ringing is no contact either
    gated_as = fit.refused_gate if fit.gate_fallback and fit.refused_gate is not None else kept
    gate = set_aside(
        fit.motion.t[use],
        residual_use,
        fit.y[use] - residual_use,
        gated_as[use],
        own_noise,
        fit.motion.time_base == "seconds",
    )
    gate["applied"] = not fit.gate_fallback
    warnings = {
        "saturated": bool(quality["saturated"]),
        "ringing": gate["ringing"] is not None,
        "gated_on_contact_free": bool(fit.settings.contact_free) and gate["share"] > CONTACT_FREE_SHARE,
        "gate_not_applied": bool(fit.gate_fallback),
        "final_above_noise": bool(np.any(over > fit.settings.warn_rms_over_noise)),
        "leftover": bool(leftover),
    }
    notes = list(notes) + quality_notes(quality, "rows" if fit.motion.time_base == "index" else "s")
    notes += set_aside_notes(gate, fit.settings.contact_free)
    for step in steps:
        if step["action"] == "set_aside":
            notes.append(
                f"{step['effect']} set aside: it gained {100 * step['evidence']['heldout_gain']:.1f} % on "
                f"held-out data but explains only {100 * step['structure_share']:.0f} % of the structure the "
                f"model leaves without it (at least {100 * fit.settings.min_structure_share:.0f} % to be "
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
            f"(above {fit.settings.warn_rms_over_noise:g}x): something the tested effects do not explain remains "
            f"(or contact the gate did not catch); see --plots"
        )
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
            + f" (threshold {threshold:.3f}x for {int(kept.sum())} samples"
            + (f", worth {independent} independent ones: the noise is coloured)" if independent < kept.sum() else ")")
            + "".join(where_text(a, where[a], fit.motion.time_base) for a in leftover)
            + "; see --plots"
        )
    folds = rounds[0][0]["folds"] if rounds and rounds[0] else None
    if folds is not None and rounds[0][0]["wins_needed"] > folds:
        notes.append(
            f"{len(fit.fit_rows)} samples give {folds} folds: no result over so few folds passes "
            f"the sign test (p ≤ {100 * fit.settings.max_sign_p:g} %), so nothing can be named"
        )
    return {
        "input": fit.stream.name,
        "samples": int(fit.n),
        "usable": int(use.sum()),
        "gated": int(use.sum() - kept.sum()),
        "fit_samples": len(fit.fit_rows),
        "time_base": fit.motion.time_base,
        "rate_hz": fit.motion.rate_hz,
        "noise_estimate": {"force_S": noise[:3].tolist(), "torque_S": noise[3:].tolist()},
        "data_quality": quality,
        "contact_gate": gate,
        "final_rms_over_noise": {"force_S": over[:3].tolist(), "torque_S": over[3:].tolist()},
        "axis_noise": {"force_S": own_noise[:3].tolist(), "torque_S": own_noise[3:].tolist()},
        "leftover": {
            "axes": leftover,
            "threshold": threshold,
            "independent_samples": independent,
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
        "batch_fit": {"rms_force_S": batch_rms_kept[0].tolist(), "rms_torque_S": batch_rms_kept[1].tolist()},
        "all_usable_rows": {
            "final_rms_force_S": rms_all[-1][:3].tolist(),
            "final_rms_torque_S": rms_all[-1][3:].tolist(),
            "batch_rms_force_S": batch_rms_all[0].tolist(),
            "batch_rms_torque_S": batch_rms_all[1].tolist(),
        },
        "rounds": rounds,
        "skipped": skipped,
        "notes": fit.notes + notes,
        "settings": dict(vars(fit.settings)),
        "_states": states,
        "_kept": kept,
    }


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
