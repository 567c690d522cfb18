"""``clock_skew``: the kinematics and sensor clocks run at different rates, so the lag between them grows.

Two computers' crystal clocks differ by 10–100 ppm, and a stream stamped by one is matched with the other's:
the lag between the streams is then τ(t) = τ₀ + s·(t − t_ref) (τ₀ at the middle of the recording, s the skew,
s/s; 100 ppm is 6 ms a minute). A constant ``time_lag`` fits its mean and leaves the rest, growing towards both
ends. Sign as ``time_lag``: τ > 0, the kinematics stream late (the pose at sensor time t is the recorded pose
at t + τ(t)).

It is a refinement of ``time_lag``, tested by the workflow beside it (``Discrepancy.candidates``, which adds it
whenever ``time_lag`` is a candidate) and named only when it beats the constant lag on held-out data
(``Discrepancy.eligible``): nested, when the lag is in the model (the skew beyond it must be significant; the
lag is then dropped by the backward test, τ₀ stands for it), or, beside a model without the lag, with a
larger gain than the lag's in the same round and a smaller held-out error in as many folds as the sign test
asks of any candidate (8 of 10). Not compensated online (the ``kalman`` estimator's lag is constant).
"""

from __future__ import annotations

from typing import cast

import numpy as np

from hapticlab.core.frames import matrix_from_quat_wxyz, quat_slerp
from hapticlab.core.sensor_model import Effect, ModelState, Motion


def resampled(motion: Motion, at: np.ndarray) -> Motion:
    """``motion``'s kinematic quantities at the times ``at`` (n,) (slerp and linear interpolation of its own
    samples, held at the ends), on its own sensor times ``t``: a shift that differs from row to row."""
    t = motion.t
    at = np.clip(at, t[0], t[-1])
    k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    span = t[k + 1] - t[k]
    u = np.clip(np.divide(at - t[k], span, out=np.zeros_like(at), where=span > 0), 0.0, 1.0)
    quat = quat_slerp(motion.quat_BE[k], motion.quat_BE[k + 1], u)

    def lerp(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else a[k] + u[:, None] * (a[k + 1] - a[k])

    return Motion(
        t,
        matrix_from_quat_wxyz(quat).transpose(0, 2, 1),
        quat,
        lerp(motion.w_E),
        lerp(motion.alpha_E),
        lerp(motion.a_B),
        motion.time_base,
        motion.rate_hz,
        motion.t_ref,
    )


class ClockSkew(Effect):
    """A lag growing linearly over the recording: τ₀ (s, at the middle) and the skew s (s/s)."""

    stage = "timing"
    labels = ("tau_s", "skew")
    steps = (5e-4, 5e-5)
    description = "kinematics and sensor clocks running at different rates"
    online = False

    def check(self, motion: Motion) -> str | None:
        if not motion.has_time:
            return "needs a time base in seconds (t counts rows here)"
        if np.abs(cast(np.ndarray, motion.w_E)).max() < 0.05:
            return "the flange hardly turns (angular speed below 0.05 rad/s)"
        half = max(float(np.ptp(motion.t)) / 2, 1e-9)
        step = 0.5 / motion.rate_hz if motion.rate_hz else 5e-4  # half a sample: central differences
        self.steps = (step, step / half)  # the skew's step moves the ends by half a sample
        return None

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        motion = state.motion
        if params[0] == 0.0 and params[1] == 0.0:
            return state
        return state.replace(motion=resampled(motion, motion.t + params[0] + params[1] * (motion.t - motion.t_ref)))

    def describe(self, params: np.ndarray) -> dict:
        return {"time_lag_s": float(params[0]), "skew": float(params[1])}

    def summary(self, params: np.ndarray) -> str:
        tau, skew = float(params[0]), float(params[1])
        late = "kinematics" if tau > 0 else "sensor"
        return f"{1e3 * tau:+.2f} ms at the middle ({late} stream late), growing {1e6 * skew:+.0f} ppm"
