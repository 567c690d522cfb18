"""The safety-critical end: turns a contact estimate into a device force command.

On any doubt (stale or missing sensor or kinematics data, an unconverged
estimator, parameters not or no longer identified, a payload change just
recognised, a saturated sensor, a non-finite value, a device error; the run
loop in ``run.py`` decides which) the command is zero at once, with the reason; otherwise the force is mapped into the
device frame, clamped to ``max_force`` and rate-limited to ``max_force_rate``.
Going to zero is never rate-limited.
"""

from __future__ import annotations

import numpy as np

from ...core.frames import matrix_from_rotvec
from ...core.types import HapticCommand

from ..config import HapticSettings

ZERO3 = np.zeros(3)


class ForceGovernor:
    """Maps, clamps and rate-limits contact forces for the haptic device.

    Args:
        settings: limits and the device mapping.
        period_s: the device command period, s (for the rate limit).
    """

    def __init__(self, settings: HapticSettings, period_s: float):
        self.settings = settings
        self.R_DB = matrix_from_rotvec(settings.rotation_DB)
        self.max_step = settings.max_force_rate * period_s
        self.last_force_D = ZERO3

    def command(self, t_ns: int, contact_force_S: np.ndarray | None, R_BS: np.ndarray | None,
                reason: str = "") -> HapticCommand:
        """The command for this device period; ``reason`` non-empty forces zero.

        Args:
            contact_force_S: (3,) the contact force in the sensor frame S, N.
            R_BS: (3, 3) orientation of S in the robot base B (R_BE·R_ES: the flange's
                orientation and the sensor's mount, identity unless an estimator knows it).
        """
        if not reason and (contact_force_S is None or R_BS is None):
            reason = "no estimate yet"
        if not reason and not np.all(np.isfinite(contact_force_S)):
            reason = "non-finite contact force"
        if reason:
            self.last_force_D = ZERO3
            return HapticCommand(t_ns, ZERO3, False, reason)
        target = self.settings.scale * (self.R_DB @ (R_BS @ contact_force_S))
        norm = float(np.linalg.norm(target))
        if norm > self.settings.max_force:
            target = target * (self.settings.max_force / norm)
        step = target - self.last_force_D
        step_norm = float(np.linalg.norm(step))
        if step_norm > self.max_step:
            target = self.last_force_D + step * (self.max_step / step_norm)
        self.last_force_D = target
        return HapticCommand(t_ns, target, True, "")
