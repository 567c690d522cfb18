"""The ``[task]`` table: what the trainee is asked to do, how it is scored, and its force limit.

A task turns a session into an exercise with an outcome (``sessions/tasks/scoring.py``): ``palpation`` (find
a stiffer inclusion under the tissue and mark it with a button press), ``retraction`` (hold the tissue at a
force inside a band for a time) or ``tracing`` (follow a line on the surface under a force limit). The
review scores it from the recording; in a simulated world, the task also places what it needs there
(``sessions/tasks/__init__.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from hapticlab.core.host.options import Check, OptionError, check, check_fields, choice, integer, number, vector

TASKS = ("palpation", "retraction", "tracing")


def _pair(key: str, value: Any) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise OptionError(key, f"must be two numbers [low, high] (N), got {value!r}")
    low, high = (number(key, v, minimum=0, maximum=1000, hint=" (N)") for v in value)
    if not low < high:
        raise OptionError(key, f"must be [low, high] with low < high (N), got {value!r}")
    return (low, high)


def _offset(key: str, value: Any) -> tuple[float, ...]:
    if isinstance(value, (list, tuple)) and len(value) == 0:
        return ()
    x, y, z = vector(key, value, hint=" (m in B; [] to draw it from world.seed)").tolist()
    return (x, y, z)


def _direction(key: str, value: Any) -> tuple[float, float, float]:
    x, y, z = vector(key, value, hint=" (a direction in B)").tolist()
    if x == y == z == 0:
        raise OptionError(key, f"must be a direction in B, not all zero, got {value!r}")
    return (x, y, z)


@dataclass(frozen=True)
class TaskSettings:
    """The ``[task]`` table (no task when ``name`` is empty).

    Attributes:
        name: ``"palpation"``, ``"retraction"`` or ``"tracing"``; ``""``: no task (the session is only recorded).
        force_limit: the force on the tissue the trainee should stay under, N: each run above it is an
            excessive-force event (3 N: around what damages bowel and vessels under a grasper, Golahmadi 2021).
        band: retraction's force band, [low, high] N.
        hold: retraction: how long the force must stay in the band, s (the score is the share of it done).
        span: palpation: the length of tissue the inclusion may be anywhere along; tracing: the line's
            length; both m at the tool, along the master's x as the haptic mapping turns it into B.
        tolerance: tracing: the RMS distance from the line at which the score reaches 0, m.
        inclusion_offset_B: palpation: where the inclusion's centre is, m in B, from where the tool tip is when
            the trainee takes control (across the surface); ``[]``: drawn from ``world.seed`` in a simulated
            world (unknown otherwise: the mark is then not scored).
        inclusion_radius: palpation: the inclusion's radius, m; a mark within it scores, one beyond 2 radii
            scores 0.
        mark_button: palpation: the bit of the master's buttons the trainee presses to mark the inclusion.
        normal_B: the tissue surface's outward normal in B (distances on the surface are taken across it).
    """

    name: str = ""
    force_limit: float = 3.0
    band: tuple[float, float] = (1.5, 2.5)
    hold: float = 2.0
    span: float = 0.03
    tolerance: float = 0.003
    inclusion_offset_B: tuple[float, ...] = ()
    inclusion_radius: float = 0.006
    mark_button: int = 1
    normal_B: tuple[float, float, float] = (0.0, 0.0, 1.0)

    CHECKS: ClassVar[Mapping[str, Check]] = {
        "name": check(choice, choices=("", *TASKS)),
        "force_limit": check(number, above=0, maximum=1000, hint=" (N)"),
        "band": _pair,
        "hold": check(number, above=0, maximum=3600, hint=" (s)"),
        "span": check(number, minimum=0, maximum=1, hint=" (m)"),
        "tolerance": check(number, above=0, maximum=1, hint=" (m)"),
        "inclusion_offset_B": _offset,
        "inclusion_radius": check(number, above=0, maximum=1, hint=" (m)"),
        "mark_button": check(integer, minimum=0, maximum=63, hint=" (a bit of the master's buttons)"),
        "normal_B": _direction,
    }

    def __post_init__(self) -> None:
        try:
            check_fields(self, self.CHECKS)
        except OptionError as exc:
            raise exc.under("task") from None
