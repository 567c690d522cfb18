"""How a session's ``[world]`` table becomes a :class:`WorldSpec`: what each key accepts, and the readers.

The records it fills are in ``params.py`` (tool, sensor, robot), ``contacts.py``, ``tissue.py``,
``cable.py`` (contacts), ``motion.py``, ``servo.py`` (motion scripts) and ``faults.py``. Every key's
check is the option toolkit's, in the ``*_OPTIONS`` dicts below (``docs/sessions.md`` is generated
from them and the records' docstrings).

The tables: ``[world]`` (``seed``, ``inertia``), ``[world.tool]``, ``[world.sensor]``,
``[world.robot]``, ``[world.motion]`` (``script`` and that script's options),
``[[world.contacts]]`` (``kind`` and that kind's options) and ``[[world.faults]]``; every key
optional but a contact's ``kind`` (and an indentation's ``start``) and a fault's ``kind`` and
``start``. Every key with its unit, default and meaning: ``docs/sessions.md``.

A wrong key or value raises :class:`hapticlab.core.errors.ConfigError` with one line naming the
full key, e.g. ``world.tool.mass: must be a finite number > 0 (kg), got 'heavy'``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import Check, OptionError, boolean, check, choice, integer, number, read_table, vector
from hapticlab.plugins.simworld.cable import Cable
from hapticlab.plugins.simworld.contacts import Contact, HangingMass, Indentation
from hapticlab.plugins.simworld.faults import DEFAULT_DURATION_S as DEFAULT_FAULT_DURATION_S
from hapticlab.plugins.simworld.faults import KINDS as FAULT_KINDS
from hapticlab.plugins.simworld.faults import Fault
from hapticlab.plugins.simworld.motion import MOTION_SCRIPTS as SCRIPTED_MOTIONS
from hapticlab.plugins.simworld.motion import MotionScript
from hapticlab.plugins.simworld.params import RobotParams, SensorParams, ToolParams, calibration_error, inertia_matrix
from hapticlab.plugins.simworld.servo import ServoedMotion
from hapticlab.plugins.simworld.tissue import Tissue

__all__ = [
    "CONTACT_KINDS",
    "CONTACT_OPTIONS",
    "FAULT_OPTIONS",
    "MOTION_OPTIONS",
    "MOTION_SCRIPTS",
    "ROBOT_OPTIONS",
    "SENSOR_OPTIONS",
    "TOOL_OPTIONS",
    "WORLD_OPTIONS",
    "WorldSpec",
    "parse_world_table",
]

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class WorldSpec:
    """Everything ``[world]`` configures, parsed and checked (the keyword arguments of SimWorld)."""

    seed: int = 1
    inertia: bool = True
    tool: ToolParams = field(default_factory=ToolParams)
    sensor: SensorParams = field(default_factory=SensorParams)
    robot: RobotParams = field(default_factory=RobotParams)
    motion: MotionScript | None = None
    contacts: tuple[Contact, ...] = ()
    faults: tuple[Fault, ...] = ()


# --------------------------------------------------------------------------- what each key accepts

MAX_SPAN_S = 86_400.0
"""s: the longest a motion's segment, dwell, hold or ramp may last (a session lasts a day at most): longer
is a typo, and its arithmetic overflows (1e300 s segments raised OverflowError inside the sim kinematics)."""
_positive = check(number, above=0)
_seconds = check(number, hint=" (s)")
_span = check(number, above=0, maximum=MAX_SPAN_S, hint=" (s)")
_pause = check(number, minimum=0, maximum=MAX_SPAN_S, hint=" (s)")
_forever = check(number, minimum=0, finite=False, hint=" (s; inf: for ever)")
_degrees = check(number, hint=" (degrees)")

TOOL_OPTIONS: dict[str, Check] = {
    "mass": check(number, above=0, hint=" (kg)"),
    "cog": vector,
    "inertia_diag": check(vector, broadcast=True, minimum=0, hint=" (kg·m²)"),
    "inertia": inertia_matrix,
    "tip": vector,
}
"""``[world.tool]``: key -> check."""
TOOL_FIELDS = {"mass": "mass", "cog": "cog_S", "inertia_diag": "inertia_S", "inertia": "inertia_S", "tip": "tip_S"}
"""``[world.tool]`` key -> ToolParams field."""

_not_negative = check(vector, broadcast=True, minimum=0)
_saturation = check(vector, broadcast=True, above=0)
SENSOR_OPTIONS: dict[str, Check] = {
    "bias_force": vector,
    "bias_torque": vector,
    "drift_force": vector,
    "drift_torque": vector,
    "drift_force_rw": _not_negative,
    "drift_torque_rw": _not_negative,
    "noise_force": _not_negative,
    "noise_torque": _not_negative,
    "saturation_force": _saturation,
    "saturation_torque": _saturation,
    "mount_rotation": vector,
    "offset": vector,
    "gain_force": calibration_error,
    "gain_torque": calibration_error,
    "warmup_force": check(vector, broadcast=True),
    "warmup_torque": check(vector, broadcast=True),
    "warmup_tau": check(number, above=0, hint=" (s)"),
    "hysteresis_force": _not_negative,
    "hysteresis_torque": _not_negative,
}
"""``[world.sensor]``: key -> check."""
SENSOR_FIELDS = {key: f"{key}_S" for key in SENSOR_OPTIONS} | {
    "mount_rotation": "mount_rotation_SE",
    "offset": "p_EoSo_E",
    "warmup_tau": "warmup_tau_s",
}
"""``[world.sensor]`` key -> SensorParams field."""

ROBOT_OPTIONS: dict[str, Check] = {
    "base_tilt": vector,
    "position": vector,
    "kinematics_lag": check(number, minimum=-1, maximum=1, hint=" (s)"),
}
"""``[world.robot]``: key -> check."""
ROBOT_FIELDS = {"base_tilt": "base_tilt_BG", "position": "p_BoEo_B", "kinematics_lag": "kinematics_lag_s"}
"""``[world.robot]`` key -> RobotParams field."""

_count = check(integer, minimum=1)
_hold = {"tilt_deg": _degrees, "tilt_axis_B": vector, "roll_deg": _degrees}
MOTION_OPTIONS: dict[str, dict[str, Check]] = {
    "random_tour": {
        "max_tilt_deg": check(number, minimum=0, maximum=180, hint=" (degrees)"),
        "max_roll_deg": check(number, minimum=0, hint=" (degrees)"),
        "segment_s": _span,
        "dwell_s": _pause,
        "max_translation": check(number, minimum=0, hint=" (m)"),
        "waypoints": _count,
    },
    "static_poses": {
        "max_tilt_deg": check(number, minimum=0, maximum=180, hint=" (degrees)"),
        "max_roll_deg": check(number, minimum=0, hint=" (degrees)"),
        "hold_s": _pause,
        "move_s": _span,
        "max_translation": check(number, minimum=0, hint=" (m)"),
        "poses": _count,
    },
    "axial_rotation": {
        "speed_deg_s": check(number, hint=" (deg/s)"),
        "duration": _span,
        "turns": _positive,
        "ramp_s": _span,
        "start_s": _pause,
        "roll0_deg": _degrees,
    },
    "hold": _hold,
    "indentation": _hold,
    "servo": {
        **_hold,
        "bandwidth_hz": check(number, above=0, hint=" (Hz)"),
        "max_speed": check(number, above=0, hint=" (m/s)"),
        "max_accel": check(number, above=0, hint=" (m/s²)"),
        "max_angular_speed": check(number, above=0, hint=" (rad/s)"),
        "max_angular_accel": check(number, above=0, hint=" (rad/s²)"),
        "step_s": _span,
        "history_s": _span,
    },
}
"""``[world.motion]``: script -> its options (``script`` itself aside; the seed and the flange position come
from ``[world]`` and ``[world.robot]``). ``indentation`` is another name of ``hold``."""
MOTION_SCRIPTS: dict[str, type[MotionScript]] = {**SCRIPTED_MOTIONS, "servo": ServoedMotion}
"""Every ``[world.motion] script``: the scripted motions, and ``servo`` (the robot follows targets sent live)."""

CONTACT_OPTIONS: dict[str, dict[str, Check]] = {
    "indentation": {
        "start": _seconds,
        "duration": _forever,
        "peak_force": check(number, minimum=0, hint=" (N)"),
        "ramp": check(number, minimum=0, hint=" (s)"),
        "direction_B": vector,
        "point_S": vector,
    },
    "hanging_mass": {
        "start": _seconds,
        "duration": _forever,
        "mass": check(number, above=0, hint=" (kg)"),
        "point_S": vector,
    },
    "tissue": {
        "surface_B": vector,
        "normal_B": vector,
        "stiffness": check(number, above=0, hint=" (N/m)"),
        "damping": check(number, minimum=0, hint=" (N·s/m)"),
        "point_S": vector,
        "inclusion_B": vector,
        "inclusion_radius": check(number, above=0, maximum=1, hint=" (m)"),
        "inclusion_stiffness": check(number, above=0, hint=" (N/m)"),
    },
    "cable": {
        "anchor_B": vector,
        "stiffness": check(number, minimum=0, hint=" (N/m)"),
        "damping": check(number, minimum=0, hint=" (N·s/m)"),
        "point_S": vector,
    },
}
"""``[[world.contacts]]``: kind -> its options (``kind`` itself aside)."""
CONTACT_KINDS: dict[str, type] = {
    "indentation": Indentation,
    "hanging_mass": HangingMass,
    "tissue": Tissue,
    "cable": Cable,
}


def _sub_table(key: str, value: Any) -> Any:
    return value  # read by its own reader, below


WORLD_OPTIONS: dict[str, Check] = {
    "seed": check(integer, minimum=0),
    "inertia": boolean,
    "tool": _sub_table,
    "sensor": _sub_table,
    "robot": _sub_table,
    "motion": _sub_table,
    "contacts": _sub_table,
    "faults": _sub_table,
}
"""``[world]``: key -> check (the sub-tables are read by their own readers)."""

FAULT_OPTIONS: dict[str, Check] = {
    "kind": check(choice, choices=FAULT_KINDS),
    "start": _seconds,
    "duration": check(number, above=0, finite=False, hint=" (s; inf: for good)"),
    "force": check(vector, hint=" (N)"),
    "torque": check(vector, hint=" (N·m)"),
    "delay": check(number, minimum=0, hint=" (s)"),
    "ramp": check(number, minimum=0, hint=" (s)"),
}
"""``[[world.faults]]``: key -> check."""


# --------------------------------------------------------------------------- readers


def _build(where: str, factory: Callable[..., T], **kwargs: Any) -> T:
    """Call a record's constructor; its OptionError names the full key, another ValueError the table."""
    try:
        return factory(**kwargs)
    except OptionError as exc:
        raise exc.under(where) from None
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _fields(opts: Mapping[str, Any], names: Mapping[str, str]) -> dict[str, Any]:
    """A table's checked values as a record's keyword arguments."""
    return {names[key]: value for key, value in opts.items()}


def parse_tool(table: Any, where: str = "world.tool") -> ToolParams:
    """ToolParams from ``[world.tool]``."""
    opts = read_table(where, table, TOOL_OPTIONS)
    if "inertia" in opts and "inertia_diag" in opts:
        raise ConfigError(f"{where}.inertia: give either inertia or inertia_diag, not both")
    if "inertia_diag" in opts:
        opts["inertia_diag"] = np.diag(opts["inertia_diag"])
    return _build(where, ToolParams, **_fields(opts, TOOL_FIELDS))


def parse_sensor(table: Any, where: str = "world.sensor") -> SensorParams:
    """SensorParams from ``[world.sensor]``."""
    return _build(where, SensorParams, **_fields(read_table(where, table, SENSOR_OPTIONS), SENSOR_FIELDS))


def parse_robot(table: Any, where: str = "world.robot") -> RobotParams:
    """RobotParams from ``[world.robot]``."""
    return _build(where, RobotParams, **_fields(read_table(where, table, ROBOT_OPTIONS), ROBOT_FIELDS))


def _kind(where: str, options: dict[str, Any], key: str, kinds: Sequence[str], default: str | None = None) -> str:
    """Pop a table's ``script``/``kind`` key, one of ``kinds``."""
    if key not in options and default is None:
        raise ConfigError(f"{where}.{key}: missing; known kinds: {', '.join(kinds)}")
    try:
        kind: str = choice(f"{where}.{key}", options.pop(key, default), tuple(kinds))
    except OptionError as exc:
        raise ConfigError(str(exc)) from None
    return kind


def parse_motion(table: Any, seed: int, robot: RobotParams, where: str = "world.motion") -> MotionScript:
    """A motion script from ``[world.motion]``; the seed and flange position come from the world."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table, got {table!r}")
    options = dict(table)
    script = _kind(where, options, "script", list(MOTION_SCRIPTS), default="random_tour")
    opts = read_table(where, options, MOTION_OPTIONS[script])
    opts = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in opts.items()}
    if script in ("random_tour", "static_poses"):
        opts["seed"] = seed
    return _build(where, MOTION_SCRIPTS[script], p_BoEo_B=robot.p_BoEo_B, **opts)


def _table_list(value: Any, where: str) -> list[tuple[str, Mapping[str, Any]]]:
    """The tables of a ``[[where]]`` list, each with its key for messages (``world.faults[2]``)."""
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: must be a list of tables ([[{where}]]), got {value!r}")
    for i, table in enumerate(value):
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where}[{i}]: must be a table, got {table!r}")
    return [(f"{where}[{i}]", table) for i, table in enumerate(value)]


def parse_contacts(value: Any, where: str = "world.contacts") -> tuple[Contact, ...]:
    """Contact events from ``[[world.contacts]]``."""
    contacts = []
    for here, table in _table_list(value, where):
        options = dict(table)
        kind = _kind(here, options, "kind", list(CONTACT_KINDS))
        opts = read_table(here, options, CONTACT_OPTIONS[kind])
        if kind == "indentation" and "start" not in opts:
            raise ConfigError(f"{here}.start: missing (time the indentation starts, s)")
        contacts.append(_build(here, CONTACT_KINDS[kind], **opts))
    return tuple(contacts)


def parse_faults(value: Any, where: str = "world.faults") -> tuple[Fault, ...]:
    """Injected faults from ``[[world.faults]]`` (see ``faults.py``)."""
    faults = []
    for here, table in _table_list(value, where):
        opts = read_table(here, table, FAULT_OPTIONS)
        if "kind" not in opts:
            raise ConfigError(f"{here}.kind: missing; known kinds: {', '.join(FAULT_KINDS)}")
        if "start" not in opts:
            raise ConfigError(f"{here}.start: missing (when the fault starts, s of world time)")
        opts.setdefault("duration", DEFAULT_FAULT_DURATION_S.get(opts["kind"], 1.0))
        opts = {k: (tuple(v.tolist()) if isinstance(v, np.ndarray) else v) for k, v in opts.items()}
        faults.append(_build(here, Fault, **opts))
    return tuple(faults)


def parse_world_table(table: Mapping[str, Any] | None, where: str = "world") -> WorldSpec:
    """Parse and check a whole ``[world]`` table.

    Raises
    ------
    ConfigError
        On an unknown key or a wrong value, naming the full key.
    """
    table = {} if table is None else table
    opts = read_table(where, table, WORLD_OPTIONS)
    seed = opts.get("seed", 1)
    robot = parse_robot(opts.get("robot", {}), f"{where}.robot")
    return WorldSpec(
        seed=seed,
        inertia=opts.get("inertia", True),
        tool=parse_tool(opts.get("tool", {}), f"{where}.tool"),
        sensor=parse_sensor(opts.get("sensor", {}), f"{where}.sensor"),
        robot=robot,
        motion=parse_motion(opts.get("motion", {}), seed, robot, f"{where}.motion"),
        contacts=parse_contacts(opts.get("contacts", []), f"{where}.contacts"),
        faults=parse_faults(opts.get("faults", []), f"{where}.faults"),
    )
