"""Training tasks: a session with an objective the review can score (``[task]``: ``settings.py``).

:func:`prepare` reads the ``[task]`` table once, before the session is built. On a real set-up it only
checks it (the review scores the recording). In a simulated world it also sets the task up there:

* ``palpation``: the tissue gets a stiffer inclusion (``plugins/simworld/tissue.py``) at a place drawn from
  ``world.seed`` along the line the master's x maps to, within ``span`` of where the tool starts;
* the simulated master's hand (``haptic.name = "sim"``) is given the task's script and timing
  (``plugins/haptics/sim_hand.py``, replacing the preset's): it searches and marks, holds, or traces; its
  moves are scaled by ``teleop.scale`` so they span the task at the tool, and the session lasts until the
  script is over.

What ``prepare`` decides (the inclusion's place, the hand's script) goes into the config, so the recording
holds the task's truth and the review scores against it.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, fields
from typing import Any

import numpy as np

from hapticlab.core.errors import ConfigError
from hapticlab.core.frames import matrix_from_rotvec
from hapticlab.core.host.options import unknown_key
from hapticlab.sessions.tasks.settings import TASKS, TaskSettings

__all__ = ["TASKS", "TaskSettings", "prepare", "task_settings"]

INCLUSION_STIFFNESS_RATIO = 3.0
"""How much stiffer than the tissue a simulated inclusion is (nodules read 3–7× their tissue, Krouskop 1998)."""
PALPATION_DEPTH = 0.0135
"""How far down the simulated hand means to press when it palpates, m at the master: a light touch, 1.2 N on
``teleop-sim``'s tissue and 2.7–3.0 N at the top of the inclusion's presses (seeds 11–13)."""
HAND = {  # the simulated hand's script per task: (script, ramp s, hold s)
    "palpation": ("palpate", 1.0, 1.0),  # (a 0.6 s press lands with a 4.5 N bounce on the inclusion)
    "retraction": ("press", 1.0, None),  # hold: the task's, plus a second
    "tracing": ("trace", 1.0, 4.0),
}


def task_settings(config: dict[str, Any]) -> TaskSettings:
    """The validated ``[task]`` table (no task when it is absent)."""
    table = config.get("task", {})
    if not isinstance(table, dict):
        raise ConfigError(f"task: must be a table, got {table!r}")
    names = [f.name for f in fields(TaskSettings)]
    for key in table:
        if key not in names:
            raise unknown_key("task", key, names)
    return TaskSettings(**table)


def prepare(config: dict[str, Any]) -> dict[str, Any]:
    """The config with its task set up (a copy; the same config when it has no task): the task's table
    resolved (every key, the inclusion's place drawn), ``session.task`` named, and in a simulated world the
    inclusion and the simulated hand's script added."""
    task = task_settings(config)
    if not task.name:
        return config
    if config.get("teleop", {}).get("enabled") is not True:
        raise ConfigError(
            f"task.name: {task.name} is done through teleoperation (a master moving the robot); set "
            "teleop.enabled = true, as the teleop-sim and teleop-emulated presets do"
        )
    config = copy.deepcopy(config)
    session = config.setdefault("session", {})
    if not session.get("task"):
        session["task"] = task.name
    tissue = _tissue(config)
    x_B = _master_x_in_B(config)
    resolved = asdict(task)
    if tissue is not None:
        resolved["normal_B"] = [float(v) for v in tissue.get("normal_B", (0.0, 0.0, 1.0))]
    if task.name == "palpation":
        offset = task.inclusion_offset_B
        if not offset and tissue is not None:
            seed = int(config.get("world", {}).get("seed", 0))
            u = np.random.default_rng([seed, 42]).uniform(-0.5, 0.5) * task.span
            offset = tuple(float(v) for v in u * x_B)
        resolved["inclusion_offset_B"] = list(offset)
        if tissue is not None and offset:
            tissue["inclusion_B"] = (np.asarray(tissue.get("surface_B", (0.45, 0.0, 0.0)), float) + offset).tolist()
            tissue["inclusion_radius"] = task.inclusion_radius
            tissue.setdefault("inclusion_stiffness", INCLUSION_STIFFNESS_RATIO * float(tissue.get("stiffness", 300.0)))
    haptic = config.get("haptic", {})
    if haptic.get("name") == "sim":
        script, ramp, hold = HAND[task.name]
        scale = float(config.get("teleop", {}).get("scale", 0.5))
        haptic.update(
            script=script, span=task.span / scale, ramp=ramp, hold=hold if hold is not None else task.hold + 1
        )
        haptic["mark_button"] = task.mark_button
        if task.name == "palpation":
            haptic["depth"] = PALPATION_DEPTH
        end = float(haptic.get("press_at", 12.0)) + _script_s(haptic)
        session["duration"] = max(float(session.get("duration", 20.0)), end + 1.0)
    config["task"] = resolved
    return config


def _tissue(config: dict[str, Any]) -> dict[str, Any] | None:
    """The simulated world's first tissue contact table (edited in place), or None."""
    world = config.get("world")
    contacts = world.get("contacts", []) if isinstance(world, dict) else []
    return next((c for c in contacts if isinstance(c, dict) and c.get("kind") == "tissue"), None)


def _master_x_in_B(config: dict[str, Any]) -> np.ndarray:
    """The master's x axis in B (the haptic mapping's ``R_BD`` first column): the hand's scripts move along it."""
    rotation = config.get("haptic", {}).get("rotation_DB", (0.0, 0.0, 0.0))
    return matrix_from_rotvec(np.asarray(rotation, dtype=float)).T[:, 0]


def _script_s(haptic: dict[str, Any]) -> float:
    """How long the simulated hand's script runs from its first move, s (``sim_hand``'s timeline)."""
    from hapticlab.plugins.haptics.sim_hand import MOVE_S

    ramp, hold = float(haptic["ramp"]), float(haptic["hold"])
    press = 2 * ramp + hold
    if haptic["script"] == "palpate":
        return (int(haptic.get("probes", 5)) + 1) * (MOVE_S + press)
    if haptic["script"] == "trace":
        return MOVE_S + press
    return press
