"""A payload that grows gradually: a reservoir on the tool filling (irrigation fluid, suction), a cable paid out.

While it grows the force on the tool is ``m(t) · g`` along gravity at ``point_S`` (quasi-static), with
``m(t) = rate · (t − start)`` from ``start`` for ``duration`` s, then held: a ramp of the weight, not the step
of a ``HangingMass``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hapticlab.core.host.options import check, check_fields, number, vector

__all__ = ["GrowingMass"]


@dataclass(frozen=True, slots=True)
class GrowingMass:
    """A mass on the tool growing at a constant rate.

    Attributes:
        rate: how fast it grows, kg/s (> 0).
        start: when it starts growing, s.
        duration: how long it grows, s (then it is held; default: for ever).
        point_S: (3,) where it hangs, in S, m; None: the tool tip.
    """

    rate: float = 0.002
    start: float = 0.0
    duration: float = math.inf
    point_S: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "rate": check(number, above=0, hint=" (kg/s)"),
                "start": check(number, hint=" (s)"),
                "duration": check(number, minimum=0, finite=False, hint=" (s)"),
            },
        )
        if self.point_S is not None:
            object.__setattr__(self, "point_S", vector("point_S", self.point_S))

    def mass(self, t: np.ndarray) -> np.ndarray:
        """(N,) the mass at times ``t`` (N,) s, kg."""
        return self.rate * np.clip(np.asarray(t, dtype=float) - self.start, 0.0, self.duration)

    def force_B(self, t: np.ndarray, gravity_accel_B: np.ndarray) -> np.ndarray:
        """(N, 3) its weight on the tool at times ``t``, in B, N."""
        return self.mass(t)[:, None] * gravity_accel_B
