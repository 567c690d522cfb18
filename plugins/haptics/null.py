"""``null``: a haptic output with no device behind it.

Accepts every command and renders nothing, so a session runs (and is recorded)
without a master device attached: the demo, tests, offline studies.
"""

from __future__ import annotations

from hapticlab.core import hookimpl
from hapticlab.core.types import DeviceState, HapticCommand


class NullHaptic:
    """A haptic output that keeps the last command and reports no device state.

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
        """No device, no state."""
        return None

    def close(self) -> None:
        """Nothing to close."""


@hookimpl
def register_haptic_outputs(register):
    register("null", NullHaptic)
