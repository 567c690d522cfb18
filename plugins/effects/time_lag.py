"""``time_lag``: the kinematics and sensor streams are offset in time (either sign).

τ > 0 means the kinematics timestamps are late by τ: the pose truly reached
at t is stamped t + τ, so the pose at sensor time t is the recorded pose at
stamp t + τ (slerp between recorded poses; the derivatives are shifted with
it). τ < 0: the sensor stream is the late one. One parameter, seconds; the
workflow's Gauss–Newton steps use the prediction's time derivative through a
central difference over one sample period, so τ may be any size the
recording's motion allows, not only a fraction of a sample.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.sensor_model import Effect, ModelState, Motion


class TimeLag(Effect):
    """Offset τ (s) of the kinematics' clock against the sensor's."""

    stage = "timing"
    labels = ("tau_s",)
    steps = (5e-4,)
    description = "kinematics and sensor streams offset in time"

    def check(self, motion: Motion) -> str | None:
        if not motion.has_time:
            return "needs a time base in seconds (t counts rows here)"
        if np.abs(cast(np.ndarray, motion.w_E)).max() < 0.05:  # (has_time: the derivatives exist)
            return "the flange hardly turns (angular speed below 0.05 rad/s)"
        # central differences over one sample period
        self.steps = (0.5 / motion.rate_hz,) if motion.rate_hz else (5e-4,)
        return None

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        return state.replace(motion=state.motion.shifted(float(params[0])))

    def describe(self, params: np.ndarray) -> dict:
        return {"time_lag_s": float(params[0])}

    def summary(self, params: np.ndarray) -> str:
        tau = float(params[0])
        late = "kinematics" if tau > 0 else "sensor"
        return f"{1e3 * tau:+.2f} ms ({late} stream late)"

    def estimator_options(self, params: np.ndarray) -> dict:
        return {"time_lag_s": float(params[0])}


@hookimpl
def register_effects(register):
    """Register ``time_lag``."""
    register("time_lag", TimeLag)
