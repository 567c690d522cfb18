"""The safety-critical end: turns a contact estimate into a device force command.

On any doubt (the gate in ``gate.py`` says which) the command is zero at once,
with the reason; otherwise the force is mapped into the device frame, clamped
to ``max_force`` and rate-limited to ``max_force_rate``. Going to zero is never
rate-limited; coming back from zero is (the ramp starts at zero).

The governor checks its *output*, not only its input: a command that is not
finite or not within the limits after the mapping (a finite but huge reading
overflows in the rotation) is replaced by zero with the reason, so nothing but
a finite force within ``max_force`` and one rate-limited step of the last
command ever reaches the device.
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
        if not reason:
            with np.errstate(over="ignore", invalid="ignore"):
                target = self.settings.scale * (self.R_DB @ (R_BS @ contact_force_S))
                norm = float(np.linalg.norm(target))
            if not np.isfinite(norm):
                reason = "non-finite force after the mapping"
        if reason:
            self.last_force_D = ZERO3
            return HapticCommand(t_ns, ZERO3, False, reason)
        if norm > self.settings.max_force:
            target = target * (self.settings.max_force / norm)
        step = target - self.last_force_D
        step_norm = float(np.linalg.norm(step))
        if step_norm > self.max_step:
            target = self.last_force_D + step * (self.max_step / step_norm)
        if not (np.all(np.isfinite(target)) and np.linalg.norm(target) <= self.settings.max_force * (1 + 1e-9)):
            self.last_force_D = ZERO3  # unreachable by the arithmetic above; checked all the same
            return HapticCommand(t_ns, ZERO3, False, "governor output out of bounds")
        self.last_force_D = target
        return HapticCommand(t_ns, target, True, "")
