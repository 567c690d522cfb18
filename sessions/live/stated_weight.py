"""A stated tool mass: the weight the motion identifies, checked against what the tool weighs.

A session that starts with the tool resting on tissue sees, while it identifies the tool, the tissue's push
with the weight: pressed straight up, any estimator takes it for a lighter tool (the push keeps its
direction in the world, as the weight does, and the moment of the push at the tip looks like a centre of
gravity moved). Nothing in the readings can tell the two until the tool is lifted, and then the missing weight
appears as a pull down that a lifted-off tool and a load hung on it make alike. Weighed (``[haptic]
tool_mass``: the tool and its adapter below the sensor's sensing plane), the tool says which:
:class:`StatedWeight` holds the force while the identified weight is off the stated one by more than
``TOLERANCE_N`` (or ``TOLERANCE_SHARE`` of it), and tells the gate when the residual shows the missing
weight (what the tool rested on is gone): the gate then has the estimator re-identify the weight.
"""

from __future__ import annotations

import math

import numpy as np

STANDARD_GRAVITY = 9.80665
"""m/s² (the weight of the stated mass; local gravity differs by under 0.3 %)."""
TOLERANCE_N = 0.3
"""The identified weight may be off the stated one by this much, N: six times the identified weight's std
the force waits for (``ready_force_std``, 0.05 N), and a few grams of cable the scale did not weigh."""
TOLERANCE_SHARE = 0.05
"""...or by this share of the stated weight (a heavy tool weighed to the percent)."""
STILL_NS = 500_000_000
"""The residual must show the missing weight, and the identified weight stay put (within half the tolerance),
this long before the weight is re-identified, ns (0.5 s): an estimator still converging (``rls``'s weight
moves by newtons in its first second) shows its own error the same way, and fixes it itself."""


class StatedWeight:
    """The weight the estimator identifies against ``mass_kg`` (module docstring)."""

    def __init__(self, mass_kg: float):
        self.mass_kg = float(mass_kg)
        self.weight_N = self.mass_kg * STANDARD_GRAVITY
        self.tolerance_N = max(TOLERANCE_N, TOLERANCE_SHARE * self.weight_N)
        self.missing_N = 0.0  # the stated weight less the identified one, N (> 0: identified lighter)
        self.reason = ""  # why the force is held ("" the weights agree)
        self.showing: tuple[int, float] | None = None  # since when the residual shows it, and the weight then
        self.reidentified = False  # the gate re-identified the weight for it (once a session: see ``gone``)

    def check(self, gravity_force_B: list[float]) -> str:
        """The identified weight (3,) N in B against the stated one: the reason the force is held ("" none)."""
        identified = math.sqrt(sum(x * x for x in gravity_force_B))
        self.missing_N = self.weight_N - identified
        self.reason = (
            ""
            if abs(self.missing_N) <= self.tolerance_N
            else f"tool weight off its stated mass (identified {identified:.2f} N, the stated {self.mass_kg:g} kg "
            f"weighs {self.weight_N:.2f} N: the tool rests on something or hangs from it; free it, or state its mass)"
        )
        return self.reason

    def step(
        self, t_ns: int, residual_B: list[float] | None, gravity_force_B: list[float]
    ) -> tuple[np.ndarray, str] | None:
        """:meth:`gone` (after :meth:`check`), as the weight step (3,) N in B and how it showed, else None."""
        if not self.gone(t_ns, residual_B, gravity_force_B):
            return None
        how = f"the residual shows the {self.missing_N:+.2f} N of weight the motion missed: now free"
        g = np.asarray(gravity_force_B, dtype=float)
        return g * (self.missing_N / np.linalg.norm(g)), how

    def gone(self, t_ns: int, residual_B: list[float] | None, gravity_force_B: list[float]) -> bool:
        """What the tool rested on (or hung from) is gone: for ``STILL_NS`` up to ``t_ns`` the residual (3,) N in
        B has been the missing weight along gravity, within the tolerance, and the identified weight has not moved
        (call after :meth:`check`; ``residual_B`` None: none yet). Once a session: a second mismatch is held, not
        re-identified (a mass stated wrong, and a contact pulling down by as much, would otherwise be learned)."""
        norm = math.sqrt(sum(x * x for x in gravity_force_B))
        if not self.reason or residual_B is None or norm == 0.0 or self.reidentified:
            self.showing = None
            return False
        along = sum(r * x for r, x in zip(residual_B, gravity_force_B)) / norm
        off = math.sqrt(max(sum(r * r for r in residual_B) - along * along, 0.0))
        if abs(along - self.missing_N) > self.tolerance_N or off > self.tolerance_N:
            self.showing = None
        elif self.showing is None or abs(norm - self.showing[1]) > self.tolerance_N / 2:
            self.showing = (t_ns, norm)
        self.reidentified = self.showing is not None and t_ns - self.showing[0] >= STILL_NS
        return self.reidentified
