"""Contact events scheduled in time: an indentation of the tool tip, a mass hung from the tool.

The other contacts depend on where the tool is (``tissue.py``, ``cable.py``); :data:`Contact` is any
of the four. Each record checks its fields once (``OptionError`` naming the field).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.host.options import OptionError, check, check_fields, number, vector
from hapticlab.plugins.simworld.cable import Cable
from hapticlab.plugins.simworld.tissue import Tissue

__all__ = ["Contact", "HangingMass", "Indentation", "direction"]


def direction(key: str, value: Any) -> np.ndarray:
    """A direction: 3 numbers, not all zero (or one for all three), normalised here."""
    vector_ = vector(key, value, broadcast=True)
    norm = np.linalg.norm(vector_)
    if norm == 0:
        raise OptionError(key, f"must be 3 numbers, not all zero (a direction), got {value!r}")
    unit = vector_ / norm
    unit.setflags(write=False)
    return unit


def _optional_point(key: str, value: Any) -> np.ndarray | None:
    return None if value is None else vector(key, value, broadcast=True)


@dataclass(frozen=True, slots=True)
class Indentation:
    """The tool tip pressed into tissue: a smooth force pulse.

    Profile: raised-cosine ramp from 0 to ``peak_force`` over ``ramp`` s, hold,
    raised-cosine ramp back to 0, ending ``duration`` s after ``start``.

    Attributes:
        start: time the force starts to rise, s.
        duration: total time from start to release, ramps included, s (>= 2·ramp).
        peak_force: force magnitude at the plateau, N.
        ramp: duration of each ramp, s (0: a step).
        direction_B: (3,) direction (normalised here) of the force the tissue
            exerts on the tool, in B (default straight up).
        point_S: (3,) where the force acts, in S, m; None: the tool tip.
    """

    start: float
    duration: float = 2.0
    peak_force: float = 2.0
    ramp: float = 0.3
    direction_B: np.ndarray = (0.0, 0.0, 1.0)  # type: ignore[assignment]  # an array after __post_init__
    point_S: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "start": check(number, hint=" (s)"),
                "duration": check(number, minimum=0, finite=False, hint=" (s)"),
                "peak_force": check(number, hint=" (N)"),
                "ramp": check(number, minimum=0, hint=" (s)"),
                "direction_B": direction,
                "point_S": _optional_point,
            },
        )
        if self.duration < 2 * self.ramp:
            raise OptionError(
                "duration", f"must be >= 2·ramp = {2 * self.ramp:g} s (a rise and a fall), got {self.duration!r}"
            )

    def profile(self, t: np.ndarray) -> np.ndarray:
        """(N,) force magnitude at times ``t`` (s), N."""
        since = np.asarray(t, dtype=float) - self.start
        if self.ramp == 0:
            return np.where((since >= 0) & (since <= self.duration), self.peak_force, 0.0)
        # 0 outside [start, start + duration] (the edge clips to 0 there), up to 1 on the plateau
        edge = np.minimum(np.maximum(np.minimum(since, self.duration - since) / self.ramp, 0.0), 1.0)
        return self.peak_force * (0.5 * (1.0 - np.cos(np.pi * edge)))

    def force_B(self, t: np.ndarray, gravity_accel_B: np.ndarray) -> np.ndarray:
        """(N, 3) force on the tool in B, N (``gravity_accel_B`` unused)."""
        return self.profile(t)[:, None] * self.direction_B


@dataclass(frozen=True, slots=True)
class HangingMass:
    """A mass hung from the tool (the paper's 104 g reference mass).

    While attached, the force on the tool is ``mass · g`` along gravity (quasi-static:
    the mass's own swinging is ignored). It is attached at ``start`` and removed
    ``duration`` s later (a step).

    Attributes:
        mass: hanging mass, kg.
        start: time it is attached, s.
        duration: time it stays attached, s (default: for ever).
        point_S: (3,) attachment point in S, m; None: the tool tip.
    """

    mass: float = 0.104
    start: float = 0.0
    duration: float = math.inf
    point_S: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "mass": check(number, above=0, hint=" (kg)"),
                "start": check(number, hint=" (s)"),
                "duration": check(number, minimum=0, finite=False, hint=" (s)"),
                "point_S": _optional_point,
            },
        )

    def force_B(self, t: np.ndarray, gravity_accel_B: np.ndarray) -> np.ndarray:
        """(N, 3) force on the tool in B, N."""
        since = np.asarray(t, dtype=float) - self.start
        attached = (since >= 0) & (since < self.duration)
        return np.where(attached[:, None], self.mass * gravity_accel_B, 0.0)


Contact = Indentation | HangingMass | Tissue | Cable
