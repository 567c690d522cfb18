"""Parameters of the simulated world, and how they are read from a session's ``[world]`` table.

Records (all SI; the frame of every vector is in its name):

* :class:`ToolParams`: what hangs on the sensor (mass, centre of mass, inertia, tip).
* :class:`SensorParams`: the F/T sensor (bias, drift, noise, saturation, mounting).
* :class:`RobotParams`: the robot base tilt against gravity and the flange home position.
* :class:`Indentation`, :class:`HangingMass`: contact events.

TOML layout (every key optional; the defaults are the dataclass defaults)::

    [world]
    seed = 1                 # integer >= 0
    inertia = true           # include the tool's inertial wrench
    [world.tool]
    mass = 0.35              # kg
    cog = [0.002, -0.001, 0.0435]      # m, in S
    inertia_diag = [...]     # kg·m² about the CoM, in S (or inertia = 3x3)
    tip = [0.0, 0.0, 0.25]   # m, in S
    [world.sensor]
    bias_force = [...]  bias_torque = [...]          # N, N·m
    drift_force = [...] drift_torque = [...]         # N/s, N·m/s
    drift_force_rw = ...  drift_torque_rw = ...      # N/√s, N·m/√s (number or 3)
    noise_force = 0.12  noise_torque = 0.01          # std, N, N·m (number or 3)
    saturation_force = [65, 65, 200]  saturation_torque = 5   # N, N·m
    mount_rotation = [0, 0, 0]  # rotation vector of R_SE, rad
    offset = [0, 0, 0]          # p_EoSo_E, m
    gain_force = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]   # calibration error G_f: read = (I + G_f)·true
    gain_torque = [[0, 0, 0], [0, 0, 0], [0, 0, 0]]  # the same for the torque
    [world.robot]
    base_tilt = [0.02, -0.01, 0.0]   # rotation vector of R_BG, rad
    position = [0.45, 0.0, 0.35]     # p_BoEo_B at the nominal pose, m
    kinematics_lag = 0.0             # s; > 0: the pose reached at t is stamped t + lag
    [world.motion]
    script = "random_tour"   # | "static_poses" | "axial_rotation" | "hold" (alias "indentation")
    ...                      # that script's options, see MOTION_OPTIONS
    [[world.contacts]]
    kind = "indentation"     # | "hanging_mass" | "tissue" | "cable"
    ...

A wrong key or value raises :class:`hapticlab.core.host.registry.ConfigError` with one
line naming the full key, e.g. ``world.tool.mass: expected a number, got 'heavy'``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2, matrix_from_rotvec
from hapticlab.core.host.registry import ConfigError
from hapticlab.plugins.simworld.cable import Cable
from hapticlab.plugins.simworld.faults import DEFAULT_DURATION_S as DEFAULT_FAULT_DURATION_S
from hapticlab.plugins.simworld.faults import KINDS as FAULT_KINDS
from hapticlab.plugins.simworld.faults import Fault
from hapticlab.plugins.simworld.motion import MOTION_SCRIPTS as SCRIPTED_MOTIONS
from hapticlab.plugins.simworld.motion import DEFAULT_P_BoEo_B, MotionScript
from hapticlab.plugins.simworld.servo import ServoedMotion
from hapticlab.plugins.simworld.tissue import Tissue

__all__ = [
    "CONTACT_KINDS",
    "MOTION_OPTIONS",
    "Contact",
    "HangingMass",
    "Indentation",
    "RobotParams",
    "SensorParams",
    "ToolParams",
    "WorldSpec",
    "parse_world_table",
]


def _vector(value: Any, name: str, shape: tuple[int, ...] = (3,)) -> np.ndarray:
    """A read-only float array of the given shape (a scalar is broadcast), or ValueError."""
    array = np.array(value, dtype=float)
    if array.ndim == 0 and shape == (3,):
        array = np.full(3, float(array))
    if array.shape != shape or not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite with shape {shape}, got {value!r}")
    array.setflags(write=False)
    return array


# --------------------------------------------------------------------------- records


@dataclass(frozen=True, slots=True)
class ToolParams:
    """The tool rigidly attached to the sensor.

    Attributes:
        mass: tool mass, kg.
        cog_S: (3,) centre of mass from the sensor origin, in S, m.
        inertia_S: (3, 3) inertia about the centre of mass, axes of S, kg·m².
        tip_S: (3,) tool tip from the sensor origin, in S, m (where indentation forces act).
    """

    mass: float = 0.35
    cog_S: np.ndarray = (0.002, -0.001, 0.0435)
    # A heavy holder near the sensor plus a slender 0.3 m shaft.
    inertia_S: np.ndarray = ((1.5e-3, 0.0, 0.0), (0.0, 1.5e-3, 0.0), (0.0, 0.0, 6.0e-5))
    tip_S: np.ndarray = (0.0, 0.0, 0.25)

    def __post_init__(self) -> None:
        if not self.mass > 0:
            raise ValueError(f"mass must be > 0 kg, got {self.mass!r}")
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "cog_S", _vector(self.cog_S, "cog_S"))
        inertia = _vector(self.inertia_S, "inertia_S", (3, 3))
        if not np.allclose(inertia, inertia.T, atol=1e-12) or np.linalg.eigvalsh(inertia).min() < -1e-12:
            raise ValueError("inertia_S must be symmetric positive semi-definite")
        object.__setattr__(self, "inertia_S", inertia)
        object.__setattr__(self, "tip_S", _vector(self.tip_S, "tip_S"))


@dataclass(frozen=True, slots=True)
class SensorParams:
    """The six-axis force/torque sensor (defaults: ATI Gamma SI-65-5 class).

    The bias at time t (s) is ``bias + drift·t + rw·W(t) + warmup·exp(−t/τ)``
    with W a standard Brownian path per axis (W(0) = 0, variance t) and τ the
    warm-up's time constant: a sensor switched on just before the session whose
    electronics are still settling (the bias ends at ``bias``).

    With a hysteresis the channels read their load (after the calibration
    error, before the bias) through a play operator of half-width r per axis
    (``core/sensor_model/play_kernel.py``): on the way up a channel reads up to r low, on
    the way down up to r high, and after a reversal it holds until the load has
    moved 2r (the loading path is followed on a 1 ms grid from t = 0).

    Attributes:
        bias_force_S: (3,) force bias at t = 0, N.
        bias_torque_S: (3,) torque bias at t = 0, N·m.
        drift_force_S: (3,) linear force-bias drift, N/s.
        drift_torque_S: (3,) linear torque-bias drift, N·m/s.
        drift_force_rw_S: (3,) random-walk force-bias drift, N/√s.
        drift_torque_rw_S: (3,) random-walk torque-bias drift, N·m/√s.
        noise_force_S: (3,) white-noise standard deviation per force axis, N.
        noise_torque_S: (3,) white-noise standard deviation per torque axis, N·m.
        saturation_force_S: (3,) range per force axis: readings are clipped to ±this, N.
        saturation_torque_S: (3,) range per torque axis, N·m.
        mount_rotation_SE: (3,) rotation vector of R_SE (the mount), rad.
        p_EoSo_E: (3,) sensor origin from the flange origin, in E, m.
        gain_force_S: (3, 3) calibration error G_f of the force channels: the
            sensor reads ``(I + G_f) · f`` for a true force f (before bias and
            noise). Its symmetric part is per-axis scale and cross-axis
            coupling; an antisymmetric part acts as a small rotation of the
            force axes. Every entry within ±0.5 (an error, not another sensor).
        gain_torque_S: (3, 3) the same for the torque channels.
        warmup_force_S: (3,) how far the force bias is from its settled value at t = 0, N.
        warmup_torque_S: (3,) the same for the torque bias, N·m.
        warmup_tau_s: the warm-up's time constant τ, s (> 0).
        hysteresis_force_S: (3,) play half-width of each force channel, N (≥ 0; 0: none).
        hysteresis_torque_S: (3,) the same for the torque channels, N·m.
    """

    bias_force_S: np.ndarray = (1.2, -0.8, 2.5)
    bias_torque_S: np.ndarray = (0.03, -0.02, 0.01)
    drift_force_S: np.ndarray = (0.0, 0.0, 0.0)
    drift_torque_S: np.ndarray = (0.0, 0.0, 0.0)
    drift_force_rw_S: np.ndarray = (0.0, 0.0, 0.0)
    drift_torque_rw_S: np.ndarray = (0.0, 0.0, 0.0)
    noise_force_S: np.ndarray = (0.12, 0.12, 0.12)
    noise_torque_S: np.ndarray = (0.01, 0.01, 0.01)
    saturation_force_S: np.ndarray = (65.0, 65.0, 200.0)
    saturation_torque_S: np.ndarray = (5.0, 5.0, 5.0)
    mount_rotation_SE: np.ndarray = (0.0, 0.0, 0.0)
    p_EoSo_E: np.ndarray = (0.0, 0.0, 0.0)
    gain_force_S: np.ndarray = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    gain_torque_S: np.ndarray = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    warmup_force_S: np.ndarray = (0.0, 0.0, 0.0)
    warmup_torque_S: np.ndarray = (0.0, 0.0, 0.0)
    warmup_tau_s: float = 20.0
    hysteresis_force_S: np.ndarray = (0.0, 0.0, 0.0)
    hysteresis_torque_S: np.ndarray = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (
            isinstance(self.warmup_tau_s, (int, float)) and math.isfinite(self.warmup_tau_s) and self.warmup_tau_s > 0
        ):
            raise ValueError(f"warmup_tau_s must be a finite number > 0, got {self.warmup_tau_s!r}")
        for name in self.__dataclass_fields__:
            if name == "warmup_tau_s":
                continue
            shape = (3, 3) if name.startswith("gain_") else (3,)
            object.__setattr__(self, name, _vector(getattr(self, name), name, shape))
        for name in ("gain_force_S", "gain_torque_S"):
            if np.abs(getattr(self, name)).max() >= 0.5:
                raise ValueError(
                    f"{name} entries must be within ±0.5 (a calibration error), got {getattr(self, name).tolist()!r}"
                )
        for name in (
            "drift_force_rw_S",
            "drift_torque_rw_S",
            "noise_force_S",
            "noise_torque_S",
            "hysteresis_force_S",
            "hysteresis_torque_S",
        ):
            if np.any(getattr(self, name) < 0):
                raise ValueError(f"{name} must be >= 0")
        for name in ("saturation_force_S", "saturation_torque_S"):
            if np.any(getattr(self, name) <= 0):
                raise ValueError(f"{name} must be > 0")

    @property
    def R_SE(self) -> np.ndarray:
        """(3, 3) mount rotation: ``v_S = R_SE @ v_E``."""
        return matrix_from_rotvec(self.mount_rotation_SE.copy())  # scipy refuses read-only arrays


@dataclass(frozen=True, slots=True)
class RobotParams:
    """The robot's installation.

    Attributes:
        base_tilt_BG: (3,) rotation vector of R_BG (orientation of the gravity
            frame G in B; a level base has zero), rad.
        p_BoEo_B: (3,) flange position at the nominal pose, in B, m (motion
            scripts move around it).
        kinematics_lag_s: offset of the kinematics stream's clock against the
            sensor's, s. Positive: the kinematics timestamps are late, the pose
            truly reached at t is stamped t + lag (so the pose reported for
            stamp t is the true pose at t − lag). Negative: the sensor stream
            is the late one. Within ±1 s.
    """

    base_tilt_BG: np.ndarray = (0.02, -0.01, 0.0)
    p_BoEo_B: np.ndarray = DEFAULT_P_BoEo_B
    kinematics_lag_s: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "base_tilt_BG", _vector(self.base_tilt_BG, "base_tilt_BG"))
        object.__setattr__(self, "p_BoEo_B", _vector(self.p_BoEo_B, "p_BoEo_B"))
        lag = float(self.kinematics_lag_s)
        if not (math.isfinite(lag) and abs(lag) <= 1.0):
            raise ValueError(f"kinematics_lag_s must be within ±1 s, got {self.kinematics_lag_s!r}")
        object.__setattr__(self, "kinematics_lag_s", lag)

    @property
    def R_BG(self) -> np.ndarray:
        """(3, 3) base tilt: ``v_B = R_BG @ v_G``."""
        return matrix_from_rotvec(self.base_tilt_BG.copy())

    @property
    def gravity_accel_B(self) -> np.ndarray:
        """(3,) gravitational acceleration in B, m/s² (``R_BG @ [0, 0, −g]``)."""
        return self.R_BG @ np.array([0.0, 0.0, -GRAVITY_M_S2])


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
    direction_B: np.ndarray = (0.0, 0.0, 1.0)
    point_S: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.duration < 0 or self.ramp < 0 or self.duration < 2 * self.ramp:
            raise ValueError(f"need 0 <= 2·ramp <= duration, got ramp={self.ramp!r}, duration={self.duration!r}")
        direction = _vector(self.direction_B, "direction_B")
        norm = np.linalg.norm(direction)
        if norm == 0:
            raise ValueError("direction_B must not be zero")
        object.__setattr__(self, "direction_B", _vector(direction / norm, "direction_B"))
        if self.point_S is not None:
            object.__setattr__(self, "point_S", _vector(self.point_S, "point_S"))

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
        if not self.mass > 0 or self.duration < 0:
            raise ValueError("need mass > 0 and duration >= 0")
        if self.point_S is not None:
            object.__setattr__(self, "point_S", _vector(self.point_S, "point_S"))

    def force_B(self, t: np.ndarray, gravity_accel_B: np.ndarray) -> np.ndarray:
        """(N, 3) force on the tool in B, N."""
        since = np.asarray(t, dtype=float) - self.start
        attached = (since >= 0) & (since < self.duration)
        return np.where(attached[:, None], self.mass * gravity_accel_B, 0.0)


Contact = Indentation | HangingMass | Tissue | Cable


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


# --------------------------------------------------------------------------- value parsers
#
# A parser takes the full key (for the message) and the TOML value and returns the
# checked value or raises ConfigError naming the key.

Parser = Callable[[str, Any], Any]


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def number(minimum: float | None = None, *, above: bool = False) -> Parser:
    """A number, optionally >= minimum (or > minimum with ``above``)."""

    def parse(key: str, value: Any) -> float:
        if not _is_number(value) or math.isnan(value):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        if minimum is not None and (value <= minimum if above else value < minimum):
            raise ConfigError(f"{key}: must be {'>' if above else '>='} {minimum:g}, got {value!r}")
        return float(value)

    return parse


def integer(minimum: int | None = None) -> Parser:
    """An integer, optionally >= minimum."""

    def parse(key: str, value: Any) -> int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise ConfigError(f"{key}: must be >= {minimum}, got {value!r}")
        return value

    return parse


def boolean(key: str, value: Any) -> bool:
    """true or false."""
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    return value


def vec3(key: str, value: Any) -> np.ndarray:
    """Three finite numbers."""
    if (
        not isinstance(value, (list, tuple))
        or len(value) != 3
        or not all(_is_number(v) and math.isfinite(v) for v in value)
    ):
        raise ConfigError(f"{key}: expected 3 numbers, got {value!r}")
    return np.array(value, dtype=float)


def number_or_vec3(minimum: float | None = None, *, above: bool = False) -> Parser:
    """One number (used for all three axes) or three numbers, each >= minimum (> with ``above``)."""

    def parse(key: str, value: Any) -> np.ndarray:
        if _is_number(value) and math.isfinite(value):
            array = np.full(3, float(value))
        elif (
            isinstance(value, (list, tuple))
            and len(value) == 3
            and all(_is_number(v) and math.isfinite(v) for v in value)
        ):
            array = np.array(value, dtype=float)
        else:
            raise ConfigError(f"{key}: expected a number or 3 numbers, got {value!r}")
        if minimum is not None and np.any(array <= minimum if above else array < minimum):
            raise ConfigError(f"{key}: must be {'>' if above else '>='} {minimum:g}, got {value!r}")
        return array

    return parse


def matrix3(key: str, value: Any) -> np.ndarray:
    """A 3x3 matrix as three rows of three numbers."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ConfigError(f"{key}: expected a 3x3 matrix (3 rows of 3 numbers), got {value!r}")
    return np.stack([vec3(f"{key}[{i}]", row) for i, row in enumerate(value)])


def gain_matrix(key: str, value: Any) -> np.ndarray:
    """A 3x3 calibration error: every entry within ±0.5."""
    matrix = matrix3(key, value)
    if np.abs(matrix).max() >= 0.5:
        raise ConfigError(f"{key}: every entry must be within ±0.5 (a calibration error), got {value!r}")
    return matrix


def lag_seconds(key: str, value: Any) -> float:
    """A time offset within ±1 s."""
    lag = number()(key, value)
    if not (math.isfinite(lag) and abs(lag) <= 1.0):
        raise ConfigError(f"{key}: must be within ±1 s, got {value!r}")
    return lag


def string(key: str, value: Any) -> str:
    """A string."""
    if not isinstance(value, str):
        raise ConfigError(f"{key}: expected a string, got {value!r}")
    return value


def read_table(where: str, table: Any, parsers: Mapping[str, Parser]) -> dict[str, Any]:
    """Check every key of a TOML table against its parser; unknown keys are errors."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in parsers:
            known = ", ".join(sorted(parsers))
            raise ConfigError(f"{where}.{key}: unknown option; known options: {known}")
        out[key] = parsers[key](f"{where}.{key}", value)
    return out


# --------------------------------------------------------------------------- tables

TOOL_OPTIONS: dict[str, Parser] = {
    "mass": number(0.0, above=True),
    "cog": vec3,
    "inertia_diag": number_or_vec3(0.0),
    "inertia": matrix3,
    "tip": vec3,
}

SENSOR_OPTIONS: dict[str, Parser] = {
    "bias_force": vec3,
    "bias_torque": vec3,
    "drift_force": vec3,
    "drift_torque": vec3,
    "drift_force_rw": number_or_vec3(0.0),
    "drift_torque_rw": number_or_vec3(0.0),
    "noise_force": number_or_vec3(0.0),
    "noise_torque": number_or_vec3(0.0),
    "saturation_force": number_or_vec3(0.0, above=True),
    "saturation_torque": number_or_vec3(0.0, above=True),
    "mount_rotation": vec3,
    "offset": vec3,
    "gain_force": gain_matrix,
    "gain_torque": gain_matrix,
    "warmup_force": number_or_vec3(),
    "warmup_torque": number_or_vec3(),
    "warmup_tau": number(0.0, above=True),
    "hysteresis_force": number_or_vec3(0.0),
    "hysteresis_torque": number_or_vec3(0.0),
}
# TOML key -> SensorParams field
_SENSOR_FIELDS = {
    "bias_force": "bias_force_S",
    "bias_torque": "bias_torque_S",
    "drift_force": "drift_force_S",
    "drift_torque": "drift_torque_S",
    "drift_force_rw": "drift_force_rw_S",
    "drift_torque_rw": "drift_torque_rw_S",
    "noise_force": "noise_force_S",
    "noise_torque": "noise_torque_S",
    "saturation_force": "saturation_force_S",
    "saturation_torque": "saturation_torque_S",
    "mount_rotation": "mount_rotation_SE",
    "offset": "p_EoSo_E",
    "gain_force": "gain_force_S",
    "gain_torque": "gain_torque_S",
    "warmup_force": "warmup_force_S",
    "warmup_torque": "warmup_torque_S",
    "warmup_tau": "warmup_tau_s",
    "hysteresis_force": "hysteresis_force_S",
    "hysteresis_torque": "hysteresis_torque_S",
}

ROBOT_OPTIONS: dict[str, Parser] = {"base_tilt": vec3, "position": vec3, "kinematics_lag": lag_seconds}

_optional_count = integer(1)
MOTION_OPTIONS: dict[str, dict[str, Parser]] = {
    "random_tour": {
        "max_tilt_deg": number(0.0),
        "max_roll_deg": number(0.0),
        "segment_s": number(0.0, above=True),
        "dwell_s": number(0.0),
        "max_translation": number(0.0),
        "waypoints": _optional_count,
    },
    "static_poses": {
        "max_tilt_deg": number(0.0),
        "max_roll_deg": number(0.0),
        "hold_s": number(0.0),
        "move_s": number(0.0, above=True),
        "max_translation": number(0.0),
        "poses": _optional_count,
    },
    "axial_rotation": {
        "speed_deg_s": number(),
        "duration": number(0.0, above=True),
        "turns": number(0.0, above=True),
        "ramp_s": number(0.0, above=True),
        "start_s": number(0.0),
        "roll0_deg": number(),
    },
    "hold": {"tilt_deg": number(), "tilt_axis_B": vec3, "roll_deg": number()},
}
MOTION_OPTIONS["indentation"] = MOTION_OPTIONS["hold"]
MOTION_OPTIONS["servo"] = {
    **MOTION_OPTIONS["hold"],
    "bandwidth_hz": number(0.0, above=True),
    "max_speed": number(0.0, above=True),
    "max_accel": number(0.0, above=True),
    "max_angular_speed": number(0.0, above=True),
    "max_angular_accel": number(0.0, above=True),
    "step_s": number(0.0, above=True),
    "history_s": number(0.0, above=True),
}
MOTION_SCRIPTS: dict[str, type[MotionScript]] = {**SCRIPTED_MOTIONS, "servo": ServoedMotion}
"""Every ``[world.motion] script``: the scripted motions, and ``servo`` (the robot follows targets sent live)."""
"""Options of each motion script (``script`` itself aside); seed and position come from elsewhere."""

CONTACT_OPTIONS: dict[str, dict[str, Parser]] = {
    "indentation": {
        "start": number(),
        "duration": number(0.0),
        "peak_force": number(0.0),
        "ramp": number(0.0),
        "direction_B": vec3,
        "point_S": vec3,
    },
    "hanging_mass": {"start": number(), "duration": number(0.0), "mass": number(0.0, above=True), "point_S": vec3},
    "tissue": {
        "surface_B": vec3,
        "normal_B": vec3,
        "stiffness": number(0.0, above=True),
        "damping": number(0.0),
        "point_S": vec3,
    },
    "cable": {"anchor_B": vec3, "stiffness": number(0.0), "damping": number(0.0), "point_S": vec3},
}
CONTACT_KINDS: dict[str, type] = {
    "indentation": Indentation,
    "hanging_mass": HangingMass,
    "tissue": Tissue,
    "cable": Cable,
}

WORLD_OPTIONS: dict[str, Parser] = {
    "seed": integer(0),
    "inertia": boolean,
    # sub-tables are parsed separately; here only their presence is accepted
    "tool": lambda key, value: value,
    "sensor": lambda key, value: value,
    "robot": lambda key, value: value,
    "motion": lambda key, value: value,
    "contacts": lambda key, value: value,
    "faults": lambda key, value: value,
}

FAULT_OPTIONS: dict[str, Parser] = {
    "kind": string,
    "start": number(),
    "duration": number(0.0, above=True),
    "force": vec3,
    "torque": vec3,
    "delay": number(0.0),
    "ramp": number(0.0),
}


def _build(where: str, factory: Callable[..., Any], **kwargs: Any) -> Any:
    """Call a record's constructor; its ValueError becomes a ConfigError naming the table."""
    try:
        return factory(**kwargs)
    except ValueError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def parse_tool(table: Any, where: str = "world.tool") -> ToolParams:
    """ToolParams from ``[world.tool]``."""
    opts = read_table(where, table, TOOL_OPTIONS)
    if "inertia" in opts and "inertia_diag" in opts:
        raise ConfigError(f"{where}.inertia: give either inertia or inertia_diag, not both")
    kwargs: dict[str, Any] = {}
    if "mass" in opts:
        kwargs["mass"] = opts["mass"]
    if "cog" in opts:
        kwargs["cog_S"] = opts["cog"]
    if "tip" in opts:
        kwargs["tip_S"] = opts["tip"]
    if "inertia_diag" in opts:
        kwargs["inertia_S"] = np.diag(opts["inertia_diag"])
    if "inertia" in opts:
        inertia = opts["inertia"]
        if not np.allclose(inertia, inertia.T) or np.linalg.eigvalsh(inertia).min() < -1e-12:
            raise ConfigError(f"{where}.inertia: must be symmetric positive semi-definite, got {table['inertia']!r}")
        kwargs["inertia_S"] = inertia
    return _build(where, ToolParams, **kwargs)


def parse_sensor(table: Any, where: str = "world.sensor") -> SensorParams:
    """SensorParams from ``[world.sensor]``."""
    opts = read_table(where, table, SENSOR_OPTIONS)
    return _build(where, SensorParams, **{_SENSOR_FIELDS[k]: v for k, v in opts.items()})


def parse_robot(table: Any, where: str = "world.robot") -> RobotParams:
    """RobotParams from ``[world.robot]``."""
    opts = read_table(where, table, ROBOT_OPTIONS)
    names = {"base_tilt": "base_tilt_BG", "position": "p_BoEo_B", "kinematics_lag": "kinematics_lag_s"}
    return _build(where, RobotParams, **{names[k]: v for k, v in opts.items()})


def parse_motion(table: Any, seed: int, robot: RobotParams, where: str = "world.motion") -> MotionScript:
    """A motion script from ``[world.motion]``; the seed and flange position come from the world."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: expected a table, got {table!r}")
    options = dict(table)
    script = string(f"{where}.script", options.pop("script", "random_tour"))
    if script not in MOTION_SCRIPTS:
        raise ConfigError(f"{where}.script: unknown motion script {script!r}; known: {', '.join(MOTION_SCRIPTS)}")
    parsers = MOTION_OPTIONS[script]
    opts = read_table(where, options, {**parsers, "script": string})
    opts = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in opts.items()}
    if script in ("random_tour", "static_poses"):
        opts["seed"] = seed
    return _build(where, MOTION_SCRIPTS[script], p_BoEo_B=robot.p_BoEo_B, **opts)


def _table_list(value: Any, where: str) -> list[tuple[str, Mapping[str, Any]]]:
    """The tables of a ``[[where]]`` list, each with its key for messages (``world.faults[2]``)."""
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: expected a list of tables ([[{where}]]), got {value!r}")
    for i, table in enumerate(value):
        if not isinstance(table, Mapping):
            raise ConfigError(f"{where}[{i}]: expected a table, got {table!r}")
    return [(f"{where}[{i}]", table) for i, table in enumerate(value)]


def parse_contacts(value: Any, where: str = "world.contacts") -> tuple[Contact, ...]:
    """Contact events from ``[[world.contacts]]``."""
    contacts = []
    for here, table in _table_list(value, where):
        options = dict(table)
        if "kind" not in options:
            raise ConfigError(f"{here}.kind: missing; known kinds: {', '.join(CONTACT_KINDS)}")
        kind = string(f"{here}.kind", options.pop("kind"))
        if kind not in CONTACT_KINDS:
            raise ConfigError(f"{here}.kind: unknown contact kind {kind!r}; known kinds: {', '.join(CONTACT_KINDS)}")
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
        for key in ("kind", "start"):
            if key not in opts:
                raise ConfigError(f"{here}.{key}: missing; known kinds: {', '.join(FAULT_KINDS)}")
        if opts["kind"] not in FAULT_KINDS:
            raise ConfigError(f"{here}.kind: unknown fault {opts['kind']!r}; known kinds: {', '.join(FAULT_KINDS)}")
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
