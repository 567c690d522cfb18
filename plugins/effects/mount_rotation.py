"""``mount_rotation``: the sensor is not mounted square on the flange (R_SE ≠ I).

The weight seen in S is ``R_SE R_EB gravity_force_B`` with ``R_SE = Exp(θ)``,
θ the rotation vector (rad, 3 parameters). The base model's
``gravity_force_B`` absorbs any rotation on the other side (a tilted robot
base), never this one, which turns with the flange. It also stands for the
antisymmetric part of a *force* calibration error (``gain_crosstalk`` is the
symmetric part); an antisymmetric *torque* calibration error leaves the force
alone, so it is not a mount rotation (and is not modelled).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.frames import matrix_from_rotvec
from hapticlab.core.sensor_model import Effect, ModelState, Motion


class MountRotation(Effect):
    """R_SE = Exp(θ), θ = (rx, ry, rz) rad."""

    stage = "mount"
    labels = ("rx_rad", "ry_rad", "rz_rad")
    steps = (1e-5, 1e-5, 1e-5)
    description = "sensor mounted rotated on the flange (R_SE ≠ I)"

    def check(self, motion: Motion) -> str | None:
        if len(motion) < 3 or np.ptp(motion.quat_BE, axis=0).max() < 1e-6:
            return "the orientation never changes"
        return None

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        return state.replace(R_SE=matrix_from_rotvec(params) @ state.R_SE)

    def describe(self, params: np.ndarray) -> dict:
        return {"mount_rotation_SE": [float(v) for v in params], "angle_deg": float(np.degrees(np.linalg.norm(params)))}

    def summary(self, params: np.ndarray) -> str:
        return f"{np.degrees(np.linalg.norm(params)):.2f}° (rotvec [{', '.join(f'{v:.4f}' for v in params)}] rad)"

    def estimator_options(self, params: np.ndarray) -> dict:
        return {"mount_rotation_SE": [float(v) for v in params]}


@hookimpl
def register_effects(register):
    """Register ``mount_rotation``."""
    register("mount_rotation", MountRotation)
