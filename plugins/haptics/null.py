"""``null``: a haptic output with no device behind it.

Accepts every command and renders nothing, so a session runs (and is recorded)
without a master device attached: the demo, tests, offline studies. It reports
a handle resting at the device's home pose, so recordings have the same
topics with or without hardware.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.types import DeviceState, HapticCommand

HOME_QUAT_DH = np.array([1.0, 0.0, 0.0, 0.0])
HOME_P_DoHo_D = np.zeros(3)


class NullHaptic:
    """A haptic output that keeps the last command; its handle rests at home.

    Args:
        rate_hz: the command rate it pretends to run at, Hz.

    Attributes:
        last: the last command sent (None before the first).
        commands: how many commands were sent.
    """

    def __init__(self, rate_hz: float = 1000.0):
        self.rate_hz = rate_hz
        self.last: HapticCommand | None = None
        self.commands = 0

    def open(self) -> None:
        """Nothing to open."""

    def send(self, command: HapticCommand) -> None:
        """Keep the command."""
        self.last = command
        self.commands += 1

    def state(self) -> DeviceState | None:
        """The handle at the home pose, no buttons, at the time of the last command."""
        t_ns = self.last.t_ns if self.last is not None else 0
        return DeviceState(t_ns, HOME_QUAT_DH, HOME_P_DoHo_D, 0)

    def close(self) -> None:
        """Nothing to close."""


@hookimpl
def register_haptic_outputs(register):
    register("null", NullHaptic)
