"""What a review of one session holds (:class:`SessionReview`, built by ``summary.review``) and its cohort row."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # annotations only: the command line's parser reads DEFAULT_FORCE_LIMIT_N without numpy
    from hapticlab.core.types import Event
    from hapticlab.sessions.review.figures import Contact, Envelope, EstimatorReview

DEFAULT_FORCE_LIMIT_N = 3.0
"""The contact force limit a review counts time above, N, unless told another or the session's task states one."""


@dataclass
class Series:
    """What the plots draw, every one bounded in size whatever the session's length.

    Attributes:
        raw: (fx..tz) raw aligned wrench of the primary estimator's samples, N and N·m.
        compensated: the primary estimator's contact wrench, same samples.
        contact_force: ‖contact force‖, N.
        command: ‖haptic command‖, N, and the share of ticks with the force on (2 columns); None when
            the review was asked without plots.
        passivity: the haptic port's energy E, J, and the damping its controller added, N·s/m (2 columns;
            teleoperation's ``/haptic/passivity``); None without plots or without that topic.
        params: (t s, {name: list}) the primary estimator's parameters as recorded (every 100 ms).
    """

    raw: Envelope
    compensated: Envelope
    contact_force: Envelope
    command: Envelope | None
    passivity: Envelope | None = None
    params: list[tuple[float, dict[str, list[float]]]] = field(default_factory=list)


@dataclass
class SessionReview:
    """A session, reviewed (:func:`review`). Times are s from the session's start, forces N."""

    path: Path
    name: str
    trainee: str
    task: str
    notes: str
    date: str
    duration_s: float
    estimator: str
    sensor_rate_hz: float
    samples: int
    lost_samples: int
    bad_samples: int
    kinematics_rate_hz: float
    poses: int
    estimators: list[EstimatorReview]
    contacts: list[Contact]
    force_limit_N: float
    over_limit_s: float
    contact_s: float
    peak_force_N: float
    haptic_on_s: float
    events: list[Event]
    complete: bool
    start_ns: int = 0
    series: Series | None = None
    port_energy_max_J: float | None = None  # teleoperation: max_t E(t), J (> 0: the port created energy)
    damping_share: float | None = None  # teleoperation: share of the ticks the passivity controller damped
    skill: dict[str, Any] = field(default_factory=dict)  # skill_names.KEYS -> value (None: not applicable)
    outcome: dict[str, Any] = field(default_factory=dict)  # the task's own figures (mark error, time in band...)
    task_settings: dict[str, Any] = field(default_factory=dict)  # the recorded [task] table ({}: no task)
    excess_events: list[tuple[float, float, float]] = field(default_factory=list)  # (start s, duration s, peak N)

    def t_s(self, t_ns: int) -> float:
        """A recorded time as s from the session's start."""
        return (t_ns - self.start_ns) / 1e9

    @property
    def primary(self) -> EstimatorReview | None:
        return next((e for e in self.estimators if e.name == self.estimator), None)

    def row(self) -> dict[str, Any]:
        """The cohort's row: one line per session (the CSV's columns, ``cohort.COLUMNS``, but the session's index
        among its trainee's, which only a cohort knows); ``review --json`` has the same keys."""
        return {
            "recording": str(self.path),
            "trainee": self.trainee,
            "task": self.task,
            "date": self.date,
            **{k: _round(v, 6) if isinstance(v, float) else v for k, v in self.skill.items()},
            "duration_s": round(self.duration_s, 3),
            "contacts": len(self.contacts),
            "force_limit_N": self.force_limit_N,
            "estimator": self.estimator,
            "parameters_known_s": parameters_known_s(self),
            "lost_samples": self.lost_samples,
            "faults": len(faults(self.events)),
            "complete": self.complete,
        }


def haptic_on_runs(events: list[Event], end_ns: int) -> list[tuple[int, int, str]]:
    """The runs of the haptic force on, from the ``haptic_enabled``/``haptic_disabled`` events: (on ns, off ns,
    why it went off: the ``haptic_disabled`` message without its prefix; "" for a run the session's end closed)."""
    runs, on_since = [], None
    for e in events:
        if e.kind == "haptic_enabled" and on_since is None:
            on_since = e.t_ns
        elif e.kind == "haptic_disabled" and on_since is not None:
            runs.append((on_since, e.t_ns, e.message.removeprefix("haptic force zeroed: ")))
            on_since = None
    if on_since is not None:
        runs.append((on_since, end_ns, ""))
    return runs


def parameters_known_s(r: Any) -> float | None:
    """When the gate first knew the force parameters (its ``parameters_known`` event), s from the start.

    The time the haptic force could first come on. The estimator's own convergence flag is no such time:
    kalman's is up within milliseconds of the start (its covariance test passes on its prior), so the old
    ``converged_s`` read 0.00 for every kalman session. None: never known (or an estimator without a
    parameter std, whose gate has no such event).
    """
    first = next((e for e in r.events if e.kind == "parameters_known"), None)
    return None if first is None else round(r.t_s(first.t_ns), 3)


ROUTINE_EVENTS = frozenset(
    {
        "session_start",
        "session_end",
        "converged",
        "identified",
        "parameters_known",
        "haptic_enabled",
        "haptic_disabled",
        "teleop",
        "teleop_engaged",
        "teleop_calibrated",
        "haptic_rearmed",
        "overrun_summary",
    }
)
"""Event kinds that are the session's ordinary course; every other kind is a fault or a fail-safe to look at."""


def faults(events: list[Event]) -> list[Event]:
    """The events an instructor should look at: faults, fail-safes, errors (not the session's ordinary course)."""
    return [e for e in events if e.kind not in ROUTINE_EVENTS]


def _round(x: float | None, digits: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, digits)
