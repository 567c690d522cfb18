"""The simulated world: one physics model behind the simulated F/T sensor and robot.

A :class:`SimWorld` holds a rigid tool on a wrist-mounted six-axis sensor
(``ToolParams``, ``SensorParams``), a robot whose base may be tilted against
gravity (``RobotParams``), a motion script for the flange (``motion/``:
``RandomTour``, ``StaticPoses``, ``AxialRotation``, ``Hold``) and contact events
(``Indentation``, ``HangingMass``, ``Tissue``, ``Cable``). The ``sim`` sensor and ``sim`` kinematics
plugins both read the same world, so the simulated wrench and pose agree.

Build one from a session's ``[world]`` table with ``SimWorld.from_config(table)``
(keys and defaults in ``docs/sessions.md``, read by ``config.py``), or from the parameter records
directly (``params.py``, ``contacts.py``).
"""

from hapticlab.plugins.simworld.cable import Cable
from hapticlab.plugins.simworld.config import WorldSpec, parse_world_table
from hapticlab.plugins.simworld.contacts import HangingMass, Indentation
from hapticlab.plugins.simworld.motion import (
    AxialRotation,
    Hold,
    MotionScript,
    MotionState,
    RandomTour,
    StaticPoses,
    make_motion,
)
from hapticlab.plugins.simworld.params import RobotParams, SensorParams, ToolParams
from hapticlab.plugins.simworld.physics import SimWorld

__all__ = [
    "AxialRotation",
    "Cable",
    "HangingMass",
    "Hold",
    "Indentation",
    "MotionScript",
    "MotionState",
    "RandomTour",
    "RobotParams",
    "SensorParams",
    "SimWorld",
    "StaticPoses",
    "ToolParams",
    "WorldSpec",
    "make_motion",
    "parse_world_table",
]
