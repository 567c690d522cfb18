"""``payload_ramp``: the tool's mass grows (or shrinks) gradually, at a constant rate over the recording.

A reservoir on the tool filling, a cable paid out: the weight changes along the run, not at one instant. With
W_S the tool's weight in S at the middle of the recording (t_ref) and s, d the rates of ``payload_change``'s
mass ratio and first moment::

    F += s · (t − t_ref) · W_S,    τ += (t − t_ref) · d × W_S

(4 parameters: 1/s and m/s). ``payload_change`` fits such a ramp as a step half-way (a 60 g ramp over 30 s:
"+29 g from 14.4 s", leaving the force at 1.04–1.1× the noise). It is the workflow's own refinement of
``payload_change``, as ``clock_skew`` is of ``time_lag`` (``Discrepancy.eligible``): a candidate whenever
``payload_change`` is, named only when it beats the step on held-out data (a larger gain, and a smaller error in
8 of 10 folds) or, beside the step, when the ramp beyond it is significant. Not compensated online (``kalman``'s
payload watch looks for steps).
"""

from __future__ import annotations

from typing import cast

import numpy as np

from hapticlab.core.frames import cross
from hapticlab.core.sensor_model import Effect, ModelState, Motion


class PayloadRamp(Effect):
    """The tool's mass ratio and first moment changing at constant rates (1/s, m/s) about the middle."""

    stage = "load"
    labels = ("mass_ratio_rate", "moment_rate_S_x", "moment_rate_S_y", "moment_rate_S_z")
    steps = (1e-5, 1e-7, 1e-7, 1e-7)
    description = "the tool's mass changing gradually"
    online = False

    def __init__(self):
        self.mass_kg = float("nan")  # the tool's at the middle, from the last weight seen (for describe)

    def check(self, motion: Motion) -> str | None:
        if motion.time_base == "index":
            return "needs a time base in seconds (t counts rows here: no history for a load to change along)"
        if len(motion) < 40 or np.ptp(motion.t) <= 0:
            return "the recording is too short to have a before and an after"
        half = float(np.ptp(motion.t)) / 2
        self.steps = (1e-4 / half, 1e-6 / half, 1e-6 / half, 1e-6 / half)  # 0.01 % of the weight at the ends
        return None

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        dt = (state.motion.t - state.motion.t_ref)[:, None]
        weight_S = state.weight_S
        s, d = float(params[0]), np.asarray(params[1:4], float)
        self.mass_kg = state.mass_kg
        force_S, torque_S = cast(np.ndarray, state.force_S), cast(np.ndarray, state.torque_S)  # set by the load stage
        return state.replace(force_S=force_S + dt * (s * weight_S), torque_S=torque_S + dt * cross(d, weight_S))

    def describe(self, params: np.ndarray) -> dict:
        s, d = float(params[0]), np.asarray(params[1:4], float)
        out = {"mass_ratio_rate": s, "moment_rate_S": d.tolist(), "mass_rate_kg_s": s * self.mass_kg}
        out["point_S"] = (d / s).tolist() if abs(s) > 1e-9 else None
        return out

    def summary(self, params: np.ndarray) -> str:
        found = self.describe(params)
        point = found["point_S"]
        where = f" at [{', '.join(f'{1e3 * v:.0f}' for v in point)}] mm" if point is not None else ""
        return (
            f"{found['mass_rate_kg_s'] * 6e4:+.1f} g/min ({6000 * found['mass_ratio_rate']:+.2f} % of the tool){where}"
        )
