"""``bias_drift``: the sensor's bias changes with time.

The bias is ``bias(t) = bias + Σ_k c_k · (t − t_ref)^k`` for k = 1..``order``
(default 1: a constant rate), force and torque each 3 per order, with t_ref
the middle of the recording, so the base model's ``bias_force_S`` and
``bias_torque_S`` are the bias there. With a time base in rows (``t`` counts
poses or samples) the rates are per row.
"""

from __future__ import annotations

from math import factorial

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.sensor_model import Effect, ModelState, Motion


class BiasDrift(Effect):
    """Bias polynomial in time: rates (N/s, N·m/s), then higher orders if asked.

    Args:
        order: the polynomial's degree (1: linear drift; 2 adds a curvature).
    """

    stage = "bias"
    description = "bias changing with time"

    def __init__(self, order: int = 1):
        if order not in (1, 2, 3):
            raise ValueError(f"order: must be 1, 2 or 3, got {order!r}")
        self.order = order
        self.per_row = False  # t counts rows (set by check)
        names = ["rate", "accel", "jerk"][:order]
        self.labels = tuple(f"{q}_{kind}_{axis}" for q in names for kind in ("force", "torque") for axis in "xyz")
        # steps: a change of ~1e-4 N (1e-5 N·m) over 100 s (or rows)
        self.steps = tuple(s / 100.0**k for k in range(1, order + 1) for s in [1e-4] * 3 + [1e-5] * 3)

    def check(self, motion: Motion) -> str | None:
        self.per_row = motion.time_base == "index"
        if len(motion) < 3 or np.ptp(motion.t) <= 0:
            return "the recording has no duration"
        return None

    def notes(self, motion: Motion) -> list[str]:
        return ["bias_drift: t counts rows here, so drift rates are per row"] if motion.time_base == "index" else []

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        dt = state.motion.t - state.motion.t_ref
        coeffs = np.asarray(params).reshape(self.order, 6)
        drift = sum(dt[:, None] ** (k + 1) * coeffs[k] for k in range(self.order))
        return state.replace(force_S=state.force_S + drift[:, :3], torque_S=state.torque_S + drift[:, 3:])

    def describe(self, params: np.ndarray) -> dict:
        coeffs = np.asarray(params).reshape(self.order, 6)
        out = {"bias_force_rate_S": coeffs[0, :3].tolist(), "bias_torque_rate_S": coeffs[0, 3:].tolist()}
        for k in range(1, self.order):  # d^k/dt^k of the polynomial at t_ref
            out[f"bias_force_d{k + 1}_S"] = (coeffs[k, :3] * factorial(k + 1)).tolist()
            out[f"bias_torque_d{k + 1}_S"] = (coeffs[k, 3:] * factorial(k + 1)).tolist()
        return out

    def summary(self, params: np.ndarray) -> str:
        rate = np.asarray(params[:6]) * (100.0 if self.per_row else 60.0)
        per = "100 rows" if self.per_row else "min"
        text = (
            f"force [{', '.join(f'{v:.3g}' for v in rate[:3])}] N/{per}, "
            f"torque [{', '.join(f'{v:.3g}' for v in rate[3:])}] N·m/{per}"
        )
        return text + (f" (polynomial of order {self.order})" if self.order > 1 else "")


@hookimpl
def register_effects(register):
    """Register ``bias_drift``."""
    register("bias_drift", BiasDrift)
