"""The ``world`` context: the simulated world built once per session from its ``[world]`` table.

The ``sim`` sensor and ``sim`` kinematics both take it (a ``world`` keyword),
so the simulated wrench and pose come from one physics model. The host knows
nothing about it: it builds every registered context whose table the session
has and hands it to the factories that accept a keyword of that name.
"""

from __future__ import annotations

from typing import Any

from hapticlab.core import hookimpl
from hapticlab.plugins.simworld.physics import SimWorld


def world(table: dict[str, Any]) -> SimWorld:
    """The session's simulated world from its ``[world]`` table (keys in ``docs/sessions.md``, read by
    ``config.py``)."""
    return SimWorld.from_config(table)


@hookimpl
def register_contexts(register):
    """Register the simulated world as the ``world`` context."""
    register("world", world)
