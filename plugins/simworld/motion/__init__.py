"""Motion scripts for the simulated robot: where the flange E is at every time.

A script maps an array of times ``t`` (s) to a :class:`MotionState`: the pose of
the flange E in the robot base B (``R_BE``, ``p_BoEo_B``) and its first and
second time derivatives. The derivatives are **analytic**, not finite
differences. Every script is built from pieces whose derivatives are exact:

* a slerp (geodesic) between two orientations with a quintic time scaling,
  ``R_BE(t) = R_BE_a · Exp(s(t) u)`` with ``u`` the rotation vector from the start
  to the end orientation, expressed in E. Because the axis ``u`` is fixed in E,
  the angular velocity of E in B, expressed in E, is exactly ``ṡ u`` and the
  angular acceleration exactly ``s̈ u``;
* a straight-line move with the same time scaling (velocity ``ṡ Δp``,
  acceleration ``s̈ Δp``);
* a rotation about E's own z axis by an angle ``φ(t)`` (``ω = φ̇ z``, ``ω̇ = φ̈ z``).

The quintic ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵`` has zero first and second derivatives at
both ends, so every script is C2-smooth (continuous angular acceleration and
linear acceleration) including at waypoints and at the end. Scripts are defined
for every t: before 0 they hold the start, after their end they hold the last
pose (random scripts without a waypoint count go on forever).

One module per script: ``hold.py`` (:class:`Hold`), ``random_tour.py``
(:class:`RandomTour`, :class:`StaticPoses`), ``axial_rotation.py``
(:class:`AxialRotation`); ``script.py`` holds what they share (the
:class:`MotionScript` interface, :class:`MotionState`, :func:`quintic`). The
servoed robot, whose motion follows targets sent while a session runs, is
``plugins/simworld/servo.py``.

Frames: B robot base, E flange. ``R_BE`` maps vectors from E into B.
"""

from __future__ import annotations

from hapticlab.core.host.options import choice
from hapticlab.plugins.simworld.motion.axial_rotation import AxialRotation
from hapticlab.plugins.simworld.motion.hold import Hold
from hapticlab.plugins.simworld.motion.random_tour import RandomTour, StaticPoses
from hapticlab.plugins.simworld.motion.script import (
    HORIZONTAL_R_BE,
    NOMINAL_R_BE,
    DEFAULT_P_BoEo_B,
    MotionScript,
    MotionState,
    quintic,
)

__all__ = [
    "HORIZONTAL_R_BE",
    "MOTION_SCRIPTS",
    "NOMINAL_R_BE",
    "AxialRotation",
    "DEFAULT_P_BoEo_B",
    "Hold",
    "MotionScript",
    "MotionState",
    "RandomTour",
    "StaticPoses",
    "make_motion",
    "quintic",
]

MOTION_SCRIPTS: dict[str, type[MotionScript]] = {
    "random_tour": RandomTour,
    "static_poses": StaticPoses,
    "axial_rotation": AxialRotation,
    "hold": Hold,
    "indentation": Hold,  # a fixed pose for indentation experiments
}
"""Script names as used in ``[world.motion] script = ...``."""


def make_motion(script: str, **options: object) -> MotionScript:
    """Build a motion script by name (see :data:`MOTION_SCRIPTS`) with its options."""
    return MOTION_SCRIPTS[choice("script", script, tuple(MOTION_SCRIPTS))](**options)
