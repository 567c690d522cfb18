"""The host's own session tables, checked once: ``[session]``, ``[haptic]`` (its mapping and safety limits)
and ``[teleop]``.

Each table is a frozen record whose docstring gives every key's unit, default and meaning, and whose
``CHECKS`` say what each key accepts (the option toolkit's checks; ``docs/sessions.md`` is generated from
both). A wrong value is a ``ConfigError`` naming the full key: ``session.duration: must be a finite
number > 0 and <= 86400 (s), got -5``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import (
    Check,
    OptionError,
    boolean,
    check,
    check_fields,
    choice,
    integer,
    number,
    text,
    unknown_key,
    vector,
)

MAX_BUTTON_BIT = 63
"""Highest button bit a re-arm or clutch button may name (``DeviceState.buttons`` is a bit mask)."""
MIN_LOOP_RATE_HZ = 100.0
"""Slowest loop accepted: haptic rendering wants 500-1000 Hz, and a slower command outlasts a tenth of the
serial master's watchdog (100 ms) that zeroes a force not renewed."""
MAX_LOOP_RATE_HZ = 10_000.0
"""Fastest loop accepted: a haptic device is commanded at 1 kHz, a Net F/T streams at 7 kHz at most."""
MAX_DURATION_S = 86_400.0
"""Longest session accepted (a day)."""


def check_duration(key: str, value: Any) -> float:
    """A session duration, s: finite, positive, at most a day (ConfigError naming ``key`` otherwise)."""
    try:
        return number(key, value, above=0, maximum=MAX_DURATION_S, hint=" (s)")
    except OptionError as exc:
        raise ConfigError(str(exc)) from None


def _rotation_vector(key: str, value: Any) -> tuple[float, float, float]:
    x, y, z = vector(key, value, hint=" (a rotation vector, rad)").tolist()
    return (x, y, z)


def _direction(key: str, value: Any) -> tuple[float, float, float]:
    x, y, z = vector(key, value, hint=" (a direction in the sensor frame; (0, 0, 0): none)").tolist()
    return (x, y, z)


def _button(what: str) -> Check:
    return check(integer, minimum=-1, maximum=MAX_BUTTON_BIT, hint=f" (a bit of the device's buttons; -1: {what})")


def _check_fields(record: Any, where: str) -> None:
    """Run a record's ``CHECKS`` on its fields; ConfigError naming ``where.key``."""
    try:
        check_fields(record, record.CHECKS)
    except OptionError as exc:
        raise exc.under(where) from None


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

    CHECKS: ClassVar[Mapping[str, Check]] = {
        "name": text,
        "duration": check(number, above=0, maximum=MAX_DURATION_S, hint=" (s)"),
        "realtime": boolean,
        "loop_rate_hz": check(number, minimum=MIN_LOOP_RATE_HZ, maximum=MAX_LOOP_RATE_HZ, hint=" (Hz)"),
        "out": text,
        "stale_timeout": check(number, minimum=0, maximum=1, hint=" (s; 0: automatic)"),
        "frozen_pose_timeout": check(number, above=0, maximum=1, hint=" (s)"),
        "max_turn_rate": check(number, above=0, maximum=1000, hint=" (rad/s)"),
        "max_speed": check(number, above=0, maximum=100, hint=" (m/s)"),
        "recording_writer": check(choice, choices=("process", "inline")),
        "realtime_priority": check(integer, minimum=0, maximum=99, hint=" (SCHED_FIFO; 0: the ordinary policy)"),
        "trainee": text,
        "task": text,
        "notes": text,
    }

    def __post_init__(self) -> None:
        _check_fields(self, "session")


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
        tare_button: bit of ``DeviceState.buttons`` whose press asks for a tare (-1 = none: only the ``t``
            key or the Python API; a tare is never taken unasked: ``sessions/live/tare.py``).
        ready_force_std: the force goes on only once the estimator's force-stage
            parameters are known to this standard deviation, N (for estimators
            that report one, e.g. ``rls``: sqrt of diag P). Algorithm 1's own
            ‖Δx‖ test also passes while a motion about a single axis leaves one
            direction unidentified; this host rule keeps the haptics off then.
        tool_mass: the mass the sensor carries below its sensing plane (the tool and its adapter), kg, weighed;
            0 = not stated. Stated, a weight the motion identifies off it by more than 0.3 N (or 5 %) holds the
            force: the session started with the tool resting on something, which the motion cannot tell from a
            lighter tool; it is re-identified once the missing weight shows as the tool is lifted.
        tool_axis: the tool's axis in the sensor frame S, from the sensor towards the tip (the usual coaxial
            mount: +z; the other way round, every contact across the tool would read as behind the sensor). A force
            across it has a lever arm its torque tells; one acting within 5 cm of the sensor, where nothing
            touches the tool, is held as no contact (``sessions/live/lever.py``). (0, 0, 0): the lever arm is
            not read (the twist test still is).
    """

    max_force: float = 4.0
    max_force_rate: float = 400.0
    scale: float = 1.0
    rotation_DB: tuple[float, float, float] = (0.0, 0.0, 0.0)
    deadband: float = 0.0
    cutoff_hz: float = 0.0
    rearm_button: int = -1
    tare_button: int = -1
    ready_force_std: float = 0.05
    tool_mass: float = 0.0
    tool_axis: tuple[float, float, float] = (0.0, 0.0, 1.0)

    CHECKS: ClassVar[Mapping[str, Check]] = {
        "max_force": check(number, above=0, hint=" (N)"),
        "max_force_rate": check(number, above=0, hint=" (N/s)"),
        "scale": check(number, minimum=0),
        "rotation_DB": _rotation_vector,
        "deadband": check(number, minimum=0, hint=" (N; 0: off)"),
        "cutoff_hz": check(number, minimum=0, maximum=MAX_LOOP_RATE_HZ, hint=" (Hz; 0: off)"),
        "rearm_button": _button("none"),
        "tare_button": _button("none"),
        "ready_force_std": check(number, above=0, hint=" (N)"),
        "tool_mass": check(number, minimum=0, maximum=100, hint=" (kg; 0: not stated)"),
        "tool_axis": _direction,
    }

    def __post_init__(self) -> None:
        _check_fields(self, "haptic")
        if self.tare_button >= 0 and self.tare_button == self.rearm_button:
            raise ConfigError(f"haptic.tare_button: {self.tare_button} is also haptic.rearm_button (one job a button)")


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
        delay_s: one-way delay of the link between the master and the robot's side, s, each way: the handle's
            state reaches teleoperation, and the force command the master, this much later (0: none; a
            remote link: 0.1–0.3 s). The simulated robot's own servo lag comes on top.
        passivity: "on": the passivity controller on the haptic port adds the least damping that keeps the port
            from putting energy into the hand (``sessions/live/passivity.py``); "off": it only observes.
        max_damping: the most damping the controller may add, N·s/m: what the device renders stably at its
            rate (from a velocity a period old: below m/T, m the handle's and hand's mass, T the period).
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
    delay_s: float = 0.0
    passivity: str = "on"
    max_damping: float = 30.0

    CHECKS: ClassVar[Mapping[str, Check]] = {
        "enabled": boolean,
        "scale": check(number, above=0, maximum=10),
        "clutch_button": _button("no clutch"),
        "max_speed": check(number, above=0, maximum=1, hint=" (m/s)"),
        "max_angular_speed": check(number, above=0, maximum=3, hint=" (rad/s)"),
        "workspace_radius": check(number, above=0, maximum=2, hint=" (m)"),
        "calibration_tilt_deg": check(number, minimum=0, maximum=60, hint=" (degrees; 0: no calibration tour)"),
        "calibration_dwell_s": check(number, above=0, maximum=60, hint=" (s)"),
        "require_haptics": boolean,
        "delay_s": check(number, minimum=0, maximum=2, hint=" (s, one way)"),
        "passivity": check(choice, choices=("on", "off")),
        "max_damping": check(number, minimum=0, maximum=500, hint=" (N·s/m)"),
    }

    def __post_init__(self) -> None:
        _check_fields(self, "teleop")


HAPTIC_SAFETY_KEYS = frozenset(f.name for f in fields(HapticSettings))
"""The ``[haptic]`` keys the host reads itself; the others are the haptic output plugin's options."""


def _settings_from(cls: type[Any], table: Any, where: str) -> Any:
    """A settings record from its table: unknown keys refused, values checked by the record."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: must be a table, got {table!r}")
    names = [f.name for f in fields(cls)]
    for key in table:
        if key not in names:
            raise unknown_key(where, key, names)
    return cls(**table)


def session_settings(config: dict[str, Any]) -> SessionSettings:
    """The validated ``[session]`` table."""
    settings: SessionSettings = _settings_from(SessionSettings, config.get("session", {}), "session")
    return settings


def haptic_settings(config: dict[str, Any]) -> HapticSettings:
    """The validated safety limits of the ``[haptic]`` table."""
    table = {k: v for k, v in config.get("haptic", {}).items() if k in HAPTIC_SAFETY_KEYS}
    settings: HapticSettings = _settings_from(HapticSettings, table, "haptic")
    return settings


def teleop_settings(config: dict[str, Any]) -> TeleopSettings:
    """The validated ``[teleop]`` table (teleoperation off when it is absent)."""
    settings: TeleopSettings = _settings_from(TeleopSettings, config.get("teleop", {}), "teleop")
    return settings
