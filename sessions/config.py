"""Session configuration: TOML presets and files, ``--set`` overrides, validation.

A session config is a TOML document with these tables (every one optional;
missing tables take the ``demo`` preset's values only when you start from it):

``[session]``   duration, realtime pacing, loop rate, output path
``[world]``     the simulated world (the ``world`` context of the simworld plugin,
                used by the ``sim`` sensor and kinematics)
``[sensor]``    ``name`` of a registered sensor plus its options
``[kinematics]`` ``name`` of a registered kinematics source plus its options
``[estimator]`` ``name`` of the estimator that drives the haptics plus its options
``[haptic]``    ``name`` of a haptic output plus its options and the safety limits
``[teleop]``    teleoperation: the master's handle moves the robot (``sessions/live/teleop.py``)
``[shadows.<label>]`` more estimators run side by side on the same samples and
                recorded on ``/estimator/<label>`` (``name`` defaults to the label)

Errors are ``ConfigError`` with one line naming the key.
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from hapticlab.core.host.registry import ConfigError, validate_options

TABLES = ("session", "sensor", "kinematics", "estimator", "haptic", "teleop", "shadows")
"""The host's own tables; a plugin's context (``register_contexts``, e.g. ``world``) adds its own."""
PLUGIN_TABLES = {"sensor": "sensor", "kinematics": "kinematics", "estimator": "estimator", "haptic": "haptic_output"}


@dataclass(frozen=True)
class SessionSettings:
    """The ``[session]`` table.

    Attributes:
        name: a label recorded with the session.
        duration: how long to run, s (Ctrl-C stops earlier).
        realtime: pace the loop to the wall clock; false runs simulated devices
            as fast as the machine allows (tests, batch generation).
        loop_rate_hz: control-loop rate; one haptic command per iteration, Hz.
        out: default output path of the recording ("" = ``recordings/<name>-<time>.mcap``).
        stale_timeout: longest age of the newest sensor sample before the
            haptic force is zeroed, s; 0 = automatic: 1.5 sensor periods plus one
            loop period (plus a networked sensor's latency, ``HasLatency``), so the
            first late sample switches the force off. At most
            1 s: a dead sensor must not leave a force on the trainee's hand longer.
        frozen_pose_timeout: longest time the robot may report bit-identical poses
            before its kinematics count as frozen (a real arm's encoders always
            jitter), s; the force is zeroed and the samples are kept from the
            estimators until the poses move again.
        max_turn_rate: fastest turn of the tool the robot can make, rad/s; two
            consecutive poses further apart are a jump (a stream that fell
            behind or caught up), the force is held off 0.5 s. The default,
            10 rad/s, is above a UR3e wrist joint's 6.28 rad/s (360°/s).
        max_speed: fastest motion of the tool the robot can make, m/s (the same
            rule; the default, 5 m/s, is a UR's highest TCP speed limit).
        recording_writer: where the MCAP writer runs: ``"process"`` (a child
            process fed one batch per tick: the writing and compression on the
            other core, and the child finishes the file if the session is
            killed) or ``"inline"`` (on the loop's thread, e.g. a one-core machine).
        realtime_priority: with ``realtime``, the loop's thread runs at this
            ``SCHED_FIFO`` priority (1-99) while it ticks, so the kernel wakes it
            on time (``sessions/live/priority.py``); 0 leaves it at the ordinary
            policy. Where it is not permitted the session runs anyway and records
            a ``realtime_priority_unavailable`` event saying why.
        trainee: who holds the master (an id your lab uses, e.g. "T07"); every review shows it, and
            a cohort review groups by it.
        task: what the session trains (e.g. "palpation", "suturing"); shown and grouped alike.
        notes: free text for the instructor (the review prints it as written).
    """

    name: str = "session"
    duration: float = 20.0
    realtime: bool = True
    loop_rate_hz: float = 1000.0
    out: str = ""
    stale_timeout: float = 0.0
    frozen_pose_timeout: float = 0.05
    max_turn_rate: float = 10.0
    max_speed: float = 5.0
    recording_writer: str = "process"
    realtime_priority: int = 50
    trainee: str = ""
    task: str = ""
    notes: str = ""

    def __post_init__(self) -> None:
        check_duration("session.duration", self.duration)
        if self.recording_writer not in ("process", "inline"):
            raise ConfigError(f'session.recording_writer: must be "process" or "inline", got {self.recording_writer!r}')
        _require("session.loop_rate_hz", self.loop_rate_hz, above=0.0, maximum=MAX_LOOP_RATE_HZ)
        _require("session.stale_timeout", self.stale_timeout, minimum=0.0, maximum=1.0)
        _require("session.frozen_pose_timeout", self.frozen_pose_timeout, above=0.0, maximum=1.0)
        _require("session.max_turn_rate", self.max_turn_rate, above=0.0, maximum=1000.0)
        _require("session.max_speed", self.max_speed, above=0.0, maximum=100.0)
        _require("session.realtime_priority", self.realtime_priority, minimum=0, maximum=99)  # SCHED_FIFO: 1-99


@dataclass(frozen=True)
class HapticSettings:
    """Safety limits and mapping of the ``[haptic]`` table (besides the plugin's own options).

    The governor (``sessions/live/safety.py``) applies them in this order:
    map → deadband → low-pass → clamp → slew-rate limit.

    Attributes:
        max_force: largest force magnitude commanded to the device, N (the device's own
            limit, when it reports one, ``HasForceLimit``, lowers it further).
        max_force_rate: largest change of the commanded force, N/s.
        scale: force scaling from the contact force to the device force.
        rotation_DB: rotation vector (rad) of the robot base B in the device base D,
            so that force_D = scale · R_DB · R_BS · contact_force_S, with
            R_BS = R_BE · R_ES (the flange's orientation and the sensor's mount).
        deadband: device forces smaller than this render as zero, N; larger ones
            lose this much of their magnitude (no step at the edge). 0 = off.
        cutoff_hz: cut-off frequency of the first-order low-pass on the device force,
            Hz; 0 = off. Discretised exactly for the loop period.
        rearm_button: bit of ``DeviceState.buttons`` whose press re-arms a latched stop
            (-1 = none: only the ``r`` key or the Python API re-arm).
        ready_force_std: the force goes on only once the estimator's force-stage
            parameters are known to this standard deviation, N (for estimators
            that report one, e.g. ``rls``: sqrt of diag P). Algorithm 1's own
            ‖Δx‖ test also passes while a motion about a single axis leaves one
            direction unidentified; this host rule keeps the haptics off then.
    """

    max_force: float = 4.0
    max_force_rate: float = 400.0
    scale: float = 1.0
    rotation_DB: tuple[float, float, float] = (0.0, 0.0, 0.0)
    deadband: float = 0.0
    cutoff_hz: float = 0.0
    rearm_button: int = -1
    ready_force_std: float = 0.05

    def __post_init__(self) -> None:
        _require("haptic.max_force", self.max_force, above=0.0)
        _require("haptic.max_force_rate", self.max_force_rate, above=0.0)
        _require("haptic.scale", self.scale, minimum=0.0)
        _require("haptic.deadband", self.deadband, minimum=0.0)
        _require("haptic.cutoff_hz", self.cutoff_hz, minimum=0.0, maximum=MAX_LOOP_RATE_HZ)
        if (
            isinstance(self.rearm_button, bool)
            or not isinstance(self.rearm_button, int)
            or not -1 <= self.rearm_button <= MAX_BUTTON_BIT
        ):
            raise ConfigError(
                f"haptic.rearm_button: must be a button bit index in 0..{MAX_BUTTON_BIT} "
                f"or -1 (none), got {self.rearm_button!r}"
            )
        _require("haptic.ready_force_std", self.ready_force_std, above=0.0)
        if len(self.rotation_DB) != 3:
            raise ConfigError(
                f"haptic.rotation_DB: must be 3 numbers (a rotation vector, rad), got {list(self.rotation_DB)!r}"
            )
        for value in self.rotation_DB:
            _require("haptic.rotation_DB", value)


@dataclass(frozen=True)
class TeleopSettings:
    """The ``[teleop]`` table: the master's handle drives the robot's flange (``sessions/live/teleop.py``).

    The handle's displacement since the robot was engaged, turned into B by the
    haptic mapping's rotation (``haptic.rotation_DB``: the same frames as the
    force, so pushing the handle along a direction moves the tool along the
    direction the force then pushes back) and scaled, is added to where the
    robot was at that moment: ``p_target = p_engaged + scale · R_BD (p_handle − p_handle_engaged)``.
    The orientation is held (3-DoF masters have no orientation).

    Attributes:
        enabled: teleoperation on (the kinematics must follow targets, ``ServosCartesian``).
        scale: robot displacement per handle displacement (motion scaling; surgical
            consoles use 0.2–0.5 for precision).
        clutch_button: bit of ``DeviceState.buttons`` that, while pressed, lets the
            handle move without the robot (repositioning the hand); -1: no clutch.
        max_speed: fastest the target may move, m/s (a handle that jumps moves the
            robot at this speed, not at once).
        max_angular_speed: fastest the target may turn, rad/s (the calibration tour's
            moves, and any return to the held orientation).
        workspace_radius: the target stays within this distance of where the robot
            was when the session began, m.
        calibration_tilt_deg: before the hand takes over, the robot visits tilted
            orientations so the estimator identifies the tool (a teleoperated tool
            at a fixed orientation never shows it); 0 = no calibration tour (use a
            warm start).
        calibration_dwell_s: time at each orientation of the calibration tour once reached, s.
        require_haptics: the robot follows only while the trainee feels the contact
            (the haptic force is on); false lets it follow without force feedback.
    """

    enabled: bool = False
    scale: float = 0.5
    clutch_button: int = -1
    max_speed: float = 0.1
    max_angular_speed: float = 0.5
    workspace_radius: float = 0.15
    calibration_tilt_deg: float = 25.0
    calibration_dwell_s: float = 1.0
    require_haptics: bool = True

    def __post_init__(self) -> None:
        _require("teleop.scale", self.scale, above=0.0, maximum=10.0)
        _require("teleop.max_speed", self.max_speed, above=0.0, maximum=1.0)
        _require("teleop.max_angular_speed", self.max_angular_speed, above=0.0, maximum=3.0)
        _require("teleop.workspace_radius", self.workspace_radius, above=0.0, maximum=2.0)
        _require("teleop.calibration_tilt_deg", self.calibration_tilt_deg, minimum=0.0, maximum=60.0)
        _require("teleop.calibration_dwell_s", self.calibration_dwell_s, above=0.0, maximum=60.0)
        if (
            isinstance(self.clutch_button, bool)
            or not isinstance(self.clutch_button, int)
            or not -1 <= self.clutch_button <= MAX_BUTTON_BIT
        ):
            raise ConfigError(
                f"teleop.clutch_button: must be a button bit index in 0..{MAX_BUTTON_BIT} "
                f"or -1 (none), got {self.clutch_button!r}"
            )


MAX_BUTTON_BIT = 63
"""Highest button bit a re-arm button may name (``DeviceState.buttons`` is a bit mask)."""
MAX_LOOP_RATE_HZ = 10_000.0
"""Fastest loop accepted: a haptic device is commanded at 1 kHz, a Net F/T streams at 7 kHz at most."""
MAX_DURATION_S = 86_400.0
"""Longest session accepted (a day)."""


def check_duration(key: str, value: float) -> float:
    """A session duration, s: finite, positive, at most a day (ConfigError naming ``key`` otherwise)."""
    _require(key, value, above=0.0, maximum=MAX_DURATION_S)
    return float(value)


def _require(
    key: str, value: float, minimum: float | None = None, above: float | None = None, maximum: float | None = None
) -> None:
    """Refuse a non-finite or out-of-range number, naming the key."""
    if not math.isfinite(value):
        raise ConfigError(f"{key}: must be a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ConfigError(f"{key}: must be at least {minimum:g}, got {value!r}")
    if above is not None and not value > above:
        raise ConfigError(f"{key}: must be greater than {above:g}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{key}: must be at most {maximum:g}, got {value!r}")


def preset_names() -> list[str]:
    """Names of the presets shipped with hapticlab."""
    folder = resources.files("hapticlab.sessions") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_config(session: str | None) -> tuple[dict[str, Any], str]:
    """The raw config of a preset name or a TOML path, and where it came from."""
    session = session or "demo"
    path = Path(session)
    # a preset name unless it looks like a path (a folder named "demo" is no session)
    if session.endswith(".toml") or "/" in session or (path.is_file() and session not in preset_names()):
        if not path.is_file():
            raise ConfigError(f"{session}: no such session file")
        text, origin = path.read_text(encoding="utf-8"), str(path)
    else:
        if session not in preset_names():
            raise ConfigError(
                f"unknown session {session!r}: not a file, and not a preset ({', '.join(preset_names())})"
            )
        text = (resources.files("hapticlab.sessions") / "presets" / f"{session}.toml").read_text("utf-8")
        origin = f"preset:{session}"
    try:
        return tomllib.loads(text), origin
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{origin}: invalid TOML: {exc}") from None


def parse_value(text: str) -> Any:
    """A ``--set`` value: TOML syntax when it parses (2, 1.5, true, [1, 2], "x"), else a bare string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def apply_overrides(config: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``--set key.path=value`` overrides (TOML values) to a copy of the config."""
    settings = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item!r}: expected key=value, e.g. estimator.name=batch")
        settings[key.strip()] = parse_value(value)
    return apply_settings(config, settings)


def apply_settings(config: dict[str, Any], settings: dict[str, Any]) -> dict[str, Any]:
    """Set ``{"dotted.key": value}`` in a copy of the config (the Python form of ``--set``).

    Setting a plugin table's ``name`` to another plugin drops the options the
    file gave the old one (they belong to it), keeping the other settings, so
    ``estimator.name = "kalman"`` works on any preset. Setting ``estimator.name``
    to an estimator the file runs as a shadow of the same label (the presets'
    ``[shadows.rls]``) promotes that shadow: it becomes the primary, with the
    options the file gave it, and no longer runs beside itself.
    """
    config = copy.deepcopy(config)
    for key, value in settings.items():
        table, _, rest = key.strip().partition(".")
        if (
            rest == "name"
            and table in PLUGIN_TABLES
            and isinstance(config.get(table), dict)
            and config[table].get("name") != value
        ):
            kept = {k: v for k, v in config[table].items() if table == "haptic" and k in HAPTIC_SAFETY_KEYS}
            shadows = config.get("shadows")
            shadow = shadows.get(value) if table == "estimator" and isinstance(shadows, dict) else None
            if isinstance(shadow, dict) and shadow.get("name", value) == value:
                kept = {**shadow, "name": value}
                del shadows[value]
                if not shadows:
                    del config["shadows"]
            config[table] = kept
    for key, value in settings.items():
        key = key.strip()
        if not key:
            raise ConfigError("settings: an empty key; give dotted keys such as session.duration")
        parts = key.split(".")
        if parts[0] not in TABLES and parts[0] not in config:
            known = (*TABLES, *_context_tables())
            if parts[0] not in known:
                raise ConfigError(f"{key}: unknown table {parts[0]!r}; tables: {', '.join(known)}")
        node = config
        for depth, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{key}: {'.'.join(parts[: depth + 1])} is not a table")
            node = child
        node[parts[-1]] = value
    return config


def _dataclass_from(cls, table: Any, where: str):
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    options = dict(table)
    validate_options(cls, options, where)
    if "rotation_DB" in options:
        options["rotation_DB"] = tuple(options["rotation_DB"])
    return cls(**{f.name: options[f.name] for f in fields(cls) if f.name in options})


def _context_tables() -> list[str]:
    """The config tables the installed plugins' contexts read (e.g. ``world``)."""
    from hapticlab.core.host.registry import Registry

    return Registry().names("context")


def check_tables(config: dict[str, Any], extra_tables: list[str] | tuple[str, ...] = ()) -> None:
    """Refuse unknown top-level tables and plugin tables without a name.

    ``extra_tables`` are the tables of the registered contexts (e.g. ``world``).
    """
    known = (*TABLES, *extra_tables)
    for key, value in config.items():
        if key not in known:
            raise ConfigError(f"{key}: unknown table; tables: {', '.join(known)}")
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {value!r}")
    for table in PLUGIN_TABLES:
        if table in config and not isinstance(config[table].get("name"), str):
            raise ConfigError(f"{table}.name: missing; name the {table} plugin to use")


def shadow_tables(config: dict[str, Any]) -> dict[str, tuple[str, dict[str, Any]]]:
    """{label: (estimator name, options)} of the ``[shadows.<label>]`` tables."""
    out = {}
    for label, table in config.get("shadows", {}).items():
        if not isinstance(table, dict):
            raise ConfigError(f"shadows.{label}: expected a table, e.g. [shadows.{label}]")
        if not label.isidentifier():
            raise ConfigError(f"shadows.{label}: a label must be a Python identifier (it names the topic)")
        options = dict(table)
        name = options.pop("name", label)
        if not isinstance(name, str):
            raise ConfigError(f"shadows.{label}.name: expected a string, got {name!r}")
        out[label] = (name, options)
    return out


def session_settings(config: dict[str, Any]) -> SessionSettings:
    """The validated ``[session]`` table."""
    return _dataclass_from(SessionSettings, config.get("session", {}), "session")


HAPTIC_SAFETY_KEYS = {f.name for f in fields(HapticSettings)}


def haptic_settings(config: dict[str, Any]) -> HapticSettings:
    """The validated safety limits of the ``[haptic]`` table."""
    table = {k: v for k, v in config.get("haptic", {}).items() if k in HAPTIC_SAFETY_KEYS}
    return _dataclass_from(HapticSettings, table, "haptic")


def teleop_settings(config: dict[str, Any]) -> TeleopSettings:
    """The validated ``[teleop]`` table (teleoperation off when it is absent)."""
    return _dataclass_from(TeleopSettings, config.get("teleop", {}), "teleop")


def plugin_options(config: dict[str, Any], table: str) -> tuple[str, dict[str, Any]]:
    """(plugin name, options) of a plugin table, without the host's own keys."""
    section = dict(config.get(table, {}))
    name = section.pop("name", None)
    if table == "haptic":
        section = {k: v for k, v in section.items() if k not in HAPTIC_SAFETY_KEYS}
    return name, section
