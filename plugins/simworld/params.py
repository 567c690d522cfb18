"""The simulated world's parameter records: the tool, the F/T sensor and the robot's installation.

All SI; the frame of every vector is in its name. Each record checks its fields once (the option
toolkit's checks, ``OptionError`` naming the field); a 3-vector field also takes one number for all
three axes. ``config.py`` reads them from a session's ``[world]`` tables.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.frames import GRAVITY_M_S2, matrix_from_rotvec
from hapticlab.core.host.options import OptionError, check, check_fields, matrix, number, vector
from hapticlab.plugins.simworld.motion import DEFAULT_P_BoEo_B

__all__ = ["RobotParams", "SensorParams", "ToolParams", "calibration_error", "inertia_matrix"]

_point = check(vector, broadcast=True)


def inertia_matrix(key: str, value: Any) -> np.ndarray:
    """An inertia about the centre of mass: a symmetric positive semi-definite 3x3 matrix, kg·m²."""
    what = "a symmetric positive semi-definite 3x3 matrix (kg·m², 3 rows of 3 numbers)"
    try:
        inertia = matrix(key, value)
    except OptionError:
        raise OptionError(key, f"must be {what}, got {value!r}") from None
    if not np.allclose(inertia, inertia.T, atol=1e-12) or np.linalg.eigvalsh(inertia).min() < -1e-12:
        raise OptionError(key, f"must be {what}, got {value!r}")
    return inertia


def calibration_error(key: str, value: Any) -> np.ndarray:
    """A sensor's calibration error G: a 3x3 matrix, every entry within ±0.5 (an error, not another sensor)."""
    what = "a 3x3 matrix (3 rows of 3 numbers), each > -0.5 and < 0.5 (a calibration error)"
    try:
        gain = matrix(key, value)
    except OptionError:
        raise OptionError(key, f"must be {what}, got {value!r}") from None
    if np.abs(gain).max() >= 0.5:
        raise OptionError(key, f"must be {what}, got {value!r}")
    return gain


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
    cog_S: np.ndarray = (0.002, -0.001, 0.0435)  # type: ignore[assignment]  # an array after __post_init__
    # A heavy holder near the sensor plus a slender 0.3 m shaft.
    inertia_S: np.ndarray = ((1.5e-3, 0.0, 0.0), (0.0, 1.5e-3, 0.0), (0.0, 0.0, 6.0e-5))  # type: ignore[assignment]  # an array after __post_init__
    tip_S: np.ndarray = (0.0, 0.0, 0.25)  # type: ignore[assignment]  # an array after __post_init__

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "mass": check(number, above=0, hint=" (kg)"),
                "cog_S": _point,
                "inertia_S": inertia_matrix,
                "tip_S": _point,
            },
        )


_positive = check(vector, broadcast=True, above=0)
_not_negative = check(vector, broadcast=True, minimum=0)
SENSOR_CHECKS = {
    "bias_force_S": _point,
    "bias_torque_S": _point,
    "drift_force_S": _point,
    "drift_torque_S": _point,
    "drift_force_rw_S": _not_negative,
    "drift_torque_rw_S": _not_negative,
    "noise_force_S": _not_negative,
    "noise_torque_S": _not_negative,
    "saturation_force_S": _positive,
    "saturation_torque_S": _positive,
    "mount_rotation_SE": _point,
    "p_EoSo_E": _point,
    "gain_force_S": calibration_error,
    "gain_torque_S": calibration_error,
    "warmup_force_S": _point,
    "warmup_torque_S": _point,
    "warmup_tau_s": check(number, above=0, hint=" (s)"),
    "hysteresis_force_S": _not_negative,
    "hysteresis_torque_S": _not_negative,
}
"""What each SensorParams field accepts."""


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

    bias_force_S: np.ndarray = (1.2, -0.8, 2.5)  # type: ignore[assignment]  # an array after __post_init__
    bias_torque_S: np.ndarray = (0.03, -0.02, 0.01)  # type: ignore[assignment]  # an array after __post_init__
    drift_force_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    drift_torque_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    drift_force_rw_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    drift_torque_rw_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    noise_force_S: np.ndarray = (0.12, 0.12, 0.12)  # type: ignore[assignment]  # an array after __post_init__
    noise_torque_S: np.ndarray = (0.01, 0.01, 0.01)  # type: ignore[assignment]  # an array after __post_init__
    saturation_force_S: np.ndarray = (65.0, 65.0, 200.0)  # type: ignore[assignment]  # an array after __post_init__
    saturation_torque_S: np.ndarray = (5.0, 5.0, 5.0)  # type: ignore[assignment]  # an array after __post_init__
    mount_rotation_SE: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    p_EoSo_E: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    gain_force_S: np.ndarray = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # type: ignore[assignment]  # an array after __post_init__
    gain_torque_S: np.ndarray = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # type: ignore[assignment]  # an array after __post_init__
    warmup_force_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    warmup_torque_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    warmup_tau_s: float = 20.0
    hysteresis_force_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    hysteresis_torque_S: np.ndarray = (0.0, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__

    def __post_init__(self) -> None:
        check_fields(self, SENSOR_CHECKS)

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

    base_tilt_BG: np.ndarray = (0.02, -0.01, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    p_BoEo_B: np.ndarray = DEFAULT_P_BoEo_B  # type: ignore[assignment]  # an array after __post_init__
    kinematics_lag_s: float = 0.0

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "base_tilt_BG": _point,
                "p_BoEo_B": _point,
                "kinematics_lag_s": check(number, minimum=-1, maximum=1, hint=" (s)"),
            },
        )

    @property
    def R_BG(self) -> np.ndarray:
        """(3, 3) base tilt: ``v_B = R_BG @ v_G``."""
        return matrix_from_rotvec(self.base_tilt_BG.copy())

    @property
    def gravity_accel_B(self) -> np.ndarray:
        """(3,) gravitational acceleration in B, m/s² (``R_BG @ [0, 0, −g]``)."""
        return self.R_BG @ np.array([0.0, 0.0, -GRAVITY_M_S2])
