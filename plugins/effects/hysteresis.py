"""``hysteresis``: each channel reads its load through a play operator (a sensor's loading hysteresis).

A strain-gauge sensor's flexure and gauge adhesive do not follow their load
exactly: loaded, a channel reads a little low, unloaded a little high, and
after the load turns back it holds until the load has moved the width of the
loop. The play (backlash) operator of half-width r models that per channel
(``core/sensor_model/play_kernel.py``)::

    h_i = min(max(h_{i−1}, x_i − r), x_i + r)

with x the load the channel sees (after the calibration error, before the
bias) and h what it reads; ``h − x`` stays within ±r. One width per channel,
force (N) then torque (N·m), in the order the rows were recorded (the operator
starts relaxed, at the first row's load). Gated rows (contact) pass through it
with the model's load, not the contact's: the loop a contact leaves behind is
not modelled.

The widths are signed: a negative one is the mirror image (a reading that
leads its load), which no sensor does, so that the prediction is an odd
function of r and its central difference at r = 0 is the hysteresis's
−sign(ẋ) (with |r| it would be 0 there and the candidate test would see
nothing). A fitted negative width is reported as such.

The ``kalman`` estimator does not model it (``online = False``): named, it is
reported as left in the haptic rendering.

What tells it from ``time_lag``: a lag's error grows with the speed (τ·ẋ), the
play's is ±r whatever the speed, and holds through reversals; fitted as a lag,
a hysteresis gives a lag that grows with its width and shrinks with the speed.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.sensor_model import Effect, ModelState, Motion
from hapticlab.core.sensor_model.play_kernel import play_signed

AXES = tuple(f"{kind}_{axis}" for kind in ("force", "torque") for axis in "xyz")


class Hysteresis(Effect):
    """Play half-widths of the six channels: force (N) then torque (N·m), signed."""

    stage = "sensor"
    labels = tuple(f"width_{a}" for a in AXES)
    steps = (1e-4,) * 3 + (1e-5,) * 3
    description = "loading hysteresis of the channels (a play operator)"
    online = False  # the kalman estimator has no hysteresis state

    def check(self, motion: Motion) -> str | None:
        if len(motion) < 10:
            return "the recording is too short for a loading loop to show"
        return None

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        if not np.any(params):
            return state
        read = play_signed(np.concatenate([state.force_S, state.torque_S], axis=1), np.asarray(params, float))
        return state.replace(force_S=read[:, :3], torque_S=read[:, 3:])

    def describe(self, params: np.ndarray) -> dict:
        return {"width_force_S": list(map(float, params[:3])), "width_torque_S": list(map(float, params[3:]))}

    def summary(self, params: np.ndarray) -> str:
        leads = " (a negative width: the reading leads its load, unphysical)" if np.any(params < 0) else ""
        return (
            f"±{', '.join(f'{v:.3g}' for v in params[:3])} N, ±{', '.join(f'{v:.3g}' for v in params[3:])} N·m{leads}"
        )


@hookimpl
def register_effects(register):
    """Register ``hysteresis``."""
    register("hysteresis", Hysteresis)
