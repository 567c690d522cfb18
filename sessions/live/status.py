"""What a running session shows and what a finished one reports."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from hapticlab.core.types import Event


@dataclass
class SessionStatus:
    """What the live terminal display shows; updated a few times a second.

    ``latched`` is True while a latched stop waits for a re-arm; ``rearm(source)``
    asks for one (the session's :meth:`LiveLoop.rearm`: honoured at the next tick,
    granted only once the cause is gone); ``tare(source)`` asks for a tare
    (:meth:`LiveLoop.tare`: granted only with the tool still and free).
    """

    elapsed_s: float = 0.0
    samples: int = 0
    rate_hz: float = 0.0
    converged_force: bool = False
    converged_torque: bool = False
    contact: bool = False
    haptic_enabled: bool = False
    reason: str = ""
    events: int = 0
    behind_s: float = 0.0
    latched: bool = False
    live_address: str = ""  # where the Foxglove live view listens ("" without one)
    teleop: str = ""  # teleoperation's mode ("following", "holding: clutch pressed", ...); "" when off
    rearm: Callable[[str], None] | None = field(default=None, repr=False)
    tare: Callable[[str], None] | None = field(default=None, repr=False)


@dataclass
class SessionResult:
    """What a finished session reports (the same numbers are in the recording's ``hapticlab.summary``).

    Attributes:
        path: the recording.
        samples, poses: wrench samples and poses recorded.
        duration_s: session time from start to end, s.
        interrupted: ended by Ctrl-C rather than by its duration.
        error: what ended the session early ("" when nothing did): the part that raised and why.
        params: the primary estimator's parameters at the end.
        events: every event recorded.
        overruns: how often the loop fell more than one period behind its rate (realtime only).
        held_out_samples: samples the primary estimator refused without calling them a contact (lone
            outliers of the sensor's noise; ``kalman``'s ``contact_after``), None for one that does not.
    """

    path: Path
    samples: int
    poses: int
    duration_s: float
    interrupted: bool
    params: dict[str, list[float]]
    events: list[Event] = field(default_factory=list)
    first_converged_force: int | None = None
    first_converged_torque: int | None = None
    contact_samples: int = 0
    haptic_on_s: float = 0.0
    error: str = ""
    overruns: int = 0
    held_out_samples: int | None = None

    @classmethod
    def from_summary(cls, path: Path, summary: dict[str, Any], duration_s: float, events: list[Event]) -> SessionResult:
        """The result of a session whose recording's ``hapticlab.summary`` is ``summary``."""
        names = {f.name for f in fields(cls)} - {"path", "duration_s", "events"}
        return cls(path=path, duration_s=duration_s, events=events, **{name: summary[name] for name in names})


class SessionError(RuntimeError):
    """A device or estimator raised and ended the session; the recording is complete.

    ``part`` names what failed (``sensor``, ``kinematics``, ``estimator``),
    ``result`` is the session's result (its ``path`` the complete recording);
    the original exception is the ``__cause__``.
    """

    def __init__(self, message: str, part: str, result: SessionResult):
        super().__init__(message)
        self.part = part
        self.result = result
