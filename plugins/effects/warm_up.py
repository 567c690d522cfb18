"""``warm_up``: the sensor's bias settles exponentially after it is switched on.

A strain-gauge sensor's electronics and gauges warm up over tens of seconds to
minutes after power-on; the bias moves along ``bias(t) = bias + a·exp(−(t − t₀)/τ)``
with t₀ the recording's first sample, so ``a`` is how far the bias was from its
settled value then (force and torque, 3 each) and the base model's
``bias_force_S`` / ``bias_torque_S`` are the settled bias. With a time base in
rows (``t`` counts poses or samples) τ is in rows.

τ cannot be linearised at a = 0 (the term is zero for any τ), so before each
candidate test the effect sets its starting τ where the current residual best
fits an exponential (:meth:`WarmUp.locate`, over time constants from three
samples to half the recording); the fit refines τ once the effect is named. A
settling slower than half the recording is, to this data, a drift: see
``docs/discrepancy.md`` for what tells the two apart.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.sensor_model import Effect, ModelState, Motion

TAU_GRID = 60
"""Time constants tried by ``locate`` (geometric, from three samples to half the recording)."""


class WarmUp(Effect):
    """Exponential settling of the bias: the distance from the settled bias at the first sample (N, N·m), then τ."""

    stage = "bias"
    description = "bias settling exponentially (a sensor warming up)"
    labels = tuple(f"settle_{kind}_{axis}" for kind in ("force", "torque") for axis in "xyz") + ("tau",)

    def __init__(self):
        self.t0 = 0.0
        self.tau0 = 1.0  # the starting τ (s or rows), set by check() and locate()
        self.tau_min = 1e-3
        self.span = 0.0  # the recording's length (s or rows)
        self.per_row = False
        self.steps = (1e-4,) * 3 + (1e-5,) * 3 + (1e-3,)

    def check(self, motion: Motion) -> str | None:
        self.per_row = motion.time_base == "index"
        span = float(np.ptp(motion.t)) if len(motion) else 0.0
        if len(motion) < 10 or span <= 0:
            return "the recording is too short for a settling to show"
        self.t0 = float(motion.t[0])
        self.span = span
        step = span / (len(motion) - 1)
        self.tau_min = 0.5 * step  # below that, the whole settling happens before the second sample
        self._grid = np.geomspace(3.0 * step, 0.5 * span, TAU_GRID)
        self._set_tau(0.25 * span)
        return None

    def _set_tau(self, tau: float) -> None:
        self.tau0 = float(tau)
        self.steps = self.steps[:6] + (1e-3 * self.tau0,)

    def locate(self, motion: Motion, residual: np.ndarray, weight_S: np.ndarray) -> None:
        """The τ of the grid whose exponential (with a constant: the bias takes up its mean) explains the most
        of ``residual``, summed over the six axes in noise units."""
        dt = motion.t - self.t0
        best, best_gain = self.tau0, 0.0
        for tau in self._grid:
            e = np.exp(-dt / tau)
            e = e - e.mean()
            ee = float(e @ e)
            if ee <= 0.0:
                continue
            gain = float(np.sum((e @ residual) ** 2)) / ee
            if gain > best_gain:
                best, best_gain = float(tau), gain
        self._set_tau(best)

    def initial(self) -> np.ndarray:
        return np.concatenate([np.zeros(6), [self.tau0]])

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        tau = max(float(params[6]), self.tau_min)
        settle = np.exp(-(state.motion.t - self.t0) / tau)[:, None] * np.asarray(params[:6])
        return state.replace(force_S=state.force_S + settle[:, :3], torque_S=state.torque_S + settle[:, 3:])

    def describe(self, params: np.ndarray) -> dict:
        unit = "rows" if self.per_row else "s"
        return {
            "settle_force_S": list(map(float, params[:3])),
            "settle_torque_S": list(map(float, params[3:6])),
            f"tau_{unit}": float(params[6]),
        }

    def summary(self, params: np.ndarray) -> str:
        unit = " rows" if self.per_row else " s"
        tau = float(params[6])
        slow = " (longer than the recording: as well a curved drift)" if tau > self.span else ""
        return (
            f"bias {', '.join(f'{v:+.3g}' for v in params[:3])} N, "
            f"{', '.join(f'{v:+.3g}' for v in params[3:6])} N·m from settled at the start, "
            f"τ {tau:.3g}{unit}{slow}"
        )


@hookimpl
def register_effects(register):
    """Register ``warm_up``."""
    register("warm_up", WarmUp)
