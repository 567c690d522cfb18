"""The ``hold`` motion script: one fixed pose, the tool pointing down, optionally tilted and rolled."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.host.options import OptionError
from hapticlab.plugins.simworld.motion.script import (
    NOMINAL_R_BE,
    DEFAULT_P_BoEo_B,
    MotionScript,
    MotionState,
    as_times,
    still,
)

__all__ = ["Hold"]


class Hold(MotionScript):
    """A fixed pose: the tool pointing down, optionally tilted and rolled.

    ``R_BE = Rot_B(tilt_axis_B, tilt_deg) · NOMINAL_R_BE · Rot_z(roll_deg)``: the
    roll turns the tool about its own axis, the tilt then leans it about an axis
    given in B. Used for contact experiments (indentation, hanging masses).

    Parameters
    ----------
    tilt_deg : tilt of the tool axis away from straight down, degrees.
    tilt_axis_B : (3,) axis of the tilt in B (normalised here).
    roll_deg : rotation of the tool about its own axis (E's z), degrees.
    p_BoEo_B : (3,) flange position in B, m.
    """

    name = "hold"

    def __init__(
        self,
        tilt_deg: float = 0.0,
        tilt_axis_B: Sequence[float] = (1.0, 0.0, 0.0),
        roll_deg: float = 0.0,
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
    ):
        axis = np.asarray(tilt_axis_B, dtype=float)
        if axis.shape != (3,) or not np.linalg.norm(axis) > 0:
            raise OptionError("tilt_axis_B", f"must be 3 numbers, not all zero (an axis), got {tilt_axis_B!r}")
        tilt = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(tilt_deg))
        roll = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(roll_deg)])
        self.R_BE = tilt.as_matrix() @ NOMINAL_R_BE @ roll.as_matrix()
        self.p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        return still(as_times(t), self.R_BE, self.p_BoEo_B)
