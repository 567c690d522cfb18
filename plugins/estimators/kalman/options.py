"""The ``kalman`` estimator's options: one frozen record, checked once when it is made.

Every option a session's ``[estimator]`` table (or ``make_estimator("kalman", ...)``) may set, with
its unit and default; the host reads the names and types from here. How the defaults were chosen,
and what each option costs, is in ``docs/estimators.md`` ("kalman").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hapticlab.core.estimation.kernels import kernel_option
from hapticlab.core.estimation.model import MAX_FORCE, MAX_TORQUE, wrench_bound
from hapticlab.core.frames import matrix_from_rotvec
from hapticlab.core.host.options import OptionError, boolean, choice, integer, number, text
from hapticlab.plugins.estimators.kalman.stage import TILT_SPAN

TORQUE_PER_FORCE = 5.0 / 65.0
"""m: the Gamma SI-65-5's torque-to-force range, which scales a force default to its torque one."""
MAX_KINEMATICS_LAG_S = 0.5
"""The longest kinematics lag (time_lag_s > 0) corrected, s: its poses are extrapolated from the
motion's derivatives, so it is meant for lags of milliseconds; beyond half a second it is a fault."""
MAX_SENSOR_LAG_S = 5.0
"""The longest sensor lag (time_lag_s < 0) corrected, s: its poses are interpolated from those
already received, kept for this long."""
EFFECT_OPTIONS = {
    "mount_rotation": "mount_rotation = true",
    "bias_drift": "bias_rate = true",
    "warm_up": "bias_rate = true",  # the bias's rate state follows the settling online
    "payload_change": "payload_change_s > 0 (the default)",
    "inertia": "inertia = true",
    "time_lag": "time_lag_s = <s>",
    "gain_crosstalk": "gain_force_S / gain_torque_S = <3x3>",
}
"""The discrepancy workflow's effect names this estimator models, and the options they stand for."""


@dataclass(frozen=True)
class KalmanOptions:
    """The options of the ``kalman`` estimator (SI units; the defaults are the fields').

    Attributes:
        noise_force: sensor force noise: "auto" (estimated as it runs) or N, std per axis (one number
            or three).
        noise_torque: sensor torque noise: "auto" or N·m, std per axis (one number or three).
        bias_force_rw: random-walk intensity of bias_force_S, N/√s (0: constant bias). The smallest
            walk that follows a 0.5 N/min warm-up drift within 5 % of a 0.12 N sensor's noise.
        bias_torque_rw: random-walk intensity of bias_torque_S, N·m/√s (the force's times 5/65).
        bias_force_tilt_rw: random-walk intensity of bias_force_S per tilt of the tool, N/√rad (the
            model error a real sensor's base model leaves moves with the tool's orientation; 0: off), or
            "auto": learnt from the data as it runs (``tilt_walk_kernel``; 0 until it has seen enough
            turns, and 0 where the model is exact). Default (None): "auto", or 0 with ``mount_rotation``,
            whose states are the tilt error the walk would stand for.
        bias_torque_tilt_rw: the same for bias_torque_S, N·m/√rad (default: the force figure times 5/65,
            the Gamma SI-65-5's torque-to-force range; with the force's "auto", its learnt figure times 5/65).
        bias_tilt_span: rad, the least turn either bias follows its tilt walk over (default 0.15 rad:
            half the learner's window), so at a high sample rate a fast turn does not let the bias take
            in a contact's ramp (0: the plain walk; without a tilt walk it changes nothing).
        bias_rate: add bias-rate states (N/s, N·m/s) to both stages.
        bias_force_rate_rw: random-walk intensity of the force-bias rate, N/s/√s.
        bias_torque_rate_rw: the same for the torque-bias rate, N·m/s/√s.
        gating: "mahalanobis" (refuse samples outside ``gate_probability``) or "none".
        gate_probability: a sample whose innovation lies outside this probability mass of the
            predicted distribution (chi-square, 3 dof) is refused; 1 never refuses.
        contact_after: a refused sample is judged a contact once it is this many refused samples in a
            row (1: every refused sample); the ones before are held out of the update but not called a
            contact (a lone outlier of the noise). The contact wrench is the same either way.
        convergence: "pose" (the wrench known at the current pose), "identified" (that, and the
            constants as the motion identifies them), "covariance" (every parameter's std from P) or
            "step" (the paper's ‖Δx‖ < 1e-3).
        converged_force_std: bound on the std of gravity_force_B and bias_force_S, N (default: half
            the estimated noise, or 0.02 N with the noise given).
        converged_torque_std: bound on the std of the torque stage's bias (about the measured force:
            ``torque_bias``) and of std(cog_S)·|gravity_force_B|, N·m (default: half the estimated noise, or
            0.002 N·m).
        prior_force_std: prior std of gravity_force_B and bias_force_S, N (a surgical tool's weight
            plus a sensor bias; far wider priors make the first samples ill-conditioned).
        prior_cog_std: prior std of cog_S, m.
        prior_torque_std: prior std of bias_torque_S, N·m.
        implementation: "auto" (the unrolled filter; with bias_rate filterpy's, or compiled under
            ``kernel = "numba"``), "fast" or "filterpy" (the reference).
        payload_change_s: after this long (s) of continuous refusal by the force stage, test whether
            the refused residual is a change of the tool's weight (a payload change); if so, re-open
            gravity and the centre of gravity (0 disables the test).
        torque_start: "early" (default: the torque stage sees every sample the force stage accepts, from the
            first; regressed on the measured force, nothing of the force stage's estimate enters it, so the
            compensated torque is an estimate from the start; its flag still waits for the force stage's) or
            "settled" (it waits until the force stage has identified the tool, and the compensated torque is the
            raw torque until then). docs/estimators.md measures both on the real recordings.
        torque_reopen_s: after this long (s) of samples the force stage accepts with its flag up but
            the torque stage refuses, re-open the torque bias (a ``torque_bias_reopened`` event) when the
            run's torque residual is more than ``torque_reopen_lever`` times its force residual (0 never).
        torque_reopen_lever: the farthest from the sensor's origin a contact can act, m (a long
            laparoscopic instrument).
        warm_start: path to a JSON file written from ``state()`` (e.g. a session's
            ``<recording>.calibration.json``): start from its x and P ("" starts cold).
        mount_rotation: estimate the sensor's mount R_SE (small angles, an error-state EKF).
        mount_rotation_SE: a known mount as a rotation vector, rad (or ``mount_R_SE``, not both).
        mount_R_SE: a known mount as a 3x3 rotation matrix.
        mount_prior_std: prior std of the estimated mount's angles, rad.
        inertia: subtract the tool's inertial force (its mass from the identified weight, the
            motion's derivatives from the poses).
        derivative_window_s: the window the motion's derivatives are fitted over, s.
        time_lag_s: the kinematics stream's lag behind the sensor, s (> 0: poses late, extrapolated;
            < 0: the sensor late, poses interpolated from the past).
        gain_force_S: a known calibration error G of the force channels (measured = (I + G)·true).
        gain_torque_S: the same for the torque channels.
        effects: the discrepancy workflow's effect names, each standing for its options
            (``EFFECT_OPTIONS``).
        max_force: a sample with a force component beyond this (N) is refused as implausible.
        max_torque: the same for a torque component (N·m).
        kernel: "numba" (the cascade compiled) or "numpy" (the Python/numpy reference).
    """

    noise_force: float | list[float] | str = "auto"
    noise_torque: float | list[float] | str = "auto"
    bias_force_rw: float = 0.005
    bias_torque_rw: float = 0.0004
    bias_force_tilt_rw: float | str | None = None
    bias_torque_tilt_rw: float | None = None
    bias_tilt_span: float = TILT_SPAN
    bias_rate: bool = False
    bias_force_rate_rw: float = 3e-4
    bias_torque_rate_rw: float = 2.5e-5
    gating: str = "mahalanobis"
    gate_probability: float = 0.9999
    contact_after: int = 2
    convergence: str = "pose"
    converged_force_std: float | None = None
    converged_torque_std: float | None = None
    prior_force_std: float = 20.0
    prior_cog_std: float = 0.5
    prior_torque_std: float = 5.0
    implementation: str = "auto"
    payload_change_s: float = 0.3
    torque_start: str = "early"
    torque_reopen_s: float = 5.0
    torque_reopen_lever: float = 0.5
    warm_start: str = ""
    mount_rotation: bool = False
    mount_rotation_SE: list[float] | None = None
    mount_R_SE: list[list[float]] | None = None
    mount_prior_std: float = 0.2
    inertia: bool = False
    derivative_window_s: float = 0.02
    time_lag_s: float = 0.0
    gain_force_S: list[list[float]] | None = None
    gain_torque_S: list[list[float]] | None = None
    effects: list[str] | None = None
    max_force: float = MAX_FORCE
    max_torque: float = MAX_TORQUE
    kernel: str = "numba"

    def __post_init__(self) -> None:
        for effect in self.effects or []:
            if effect not in EFFECT_OPTIONS:
                raise OptionError(
                    "effects",
                    f"unknown effect {effect!r}; the kalman estimator models {', '.join(sorted(EFFECT_OPTIONS))}",
                )
        named = set(self.effects or [])
        if "time_lag" in named and not self.time_lag_s:
            raise OptionError("effects", "'time_lag' needs its value: set time_lag_s (s, from hapticlab discrepancy)")
        if "payload_change" in named and not self.payload_change_s:
            raise OptionError(
                "effects", "'payload_change' is watched for with payload_change_s > 0 (default 0.3 s), not 0"
            )
        if "gain_crosstalk" in named and self.gain_force_S is None and self.gain_torque_S is None:
            raise OptionError(
                "effects",
                "'gain_crosstalk' needs its value: set gain_force_S and/or gain_torque_S (from hapticlab discrepancy)",
            )
        for key in ("noise_force", "noise_torque"):
            if getattr(self, key) != "auto":
                noise_axes(key, getattr(self, key))
        if self.bias_force_tilt_rw != "auto" and self.bias_force_tilt_rw is not None:
            number("bias_force_tilt_rw", self.bias_force_tilt_rw, minimum=0, hint=" or 'auto'")
        for key in (
            "bias_force_rw",
            "bias_torque_rw",
            "bias_torque_tilt_rw",
            "bias_force_rate_rw",
            "bias_torque_rate_rw",
        ):
            if getattr(self, key) is not None:
                number(key, getattr(self, key), minimum=0)
        number("bias_tilt_span", self.bias_tilt_span, minimum=0, hint=" (rad; 0: the plain tilt walk)")
        for key in ("converged_force_std", "converged_torque_std"):
            if getattr(self, key) is not None:
                number(key, getattr(self, key), above=0)
        for key in ("prior_force_std", "prior_cog_std", "prior_torque_std", "mount_prior_std", "derivative_window_s"):
            number(key, getattr(self, key), above=0)
        choice("gating", self.gating, ("mahalanobis", "none"))
        choice(
            "convergence",
            self.convergence,
            ("pose", "identified", "covariance", "step"),
            hint=" (the paper's ‖Δx‖ < 1e-3)",
        )
        if not (is_plain_number(self.gate_probability) and 0 < self.gate_probability <= 1):
            raise OptionError("gate_probability", f"must be in (0, 1], got {self.gate_probability!r}")
        integer("contact_after", self.contact_after, minimum=1, hint=" (refused samples in a row)")
        for key in ("bias_rate", "mount_rotation", "inertia"):
            boolean(key, getattr(self, key))
        choice("implementation", self.implementation, ("auto", "fast", "filterpy"))
        if self.implementation == "fast" and self.resolved_bias_rate:
            raise OptionError("implementation", "'fast' has no bias-rate states; use 'auto' or 'filterpy'")
        number("payload_change_s", self.payload_change_s, minimum=0)
        choice("torque_start", self.torque_start, ("settled", "early"))
        number("torque_reopen_s", self.torque_reopen_s, minimum=0)
        number("torque_reopen_lever", self.torque_reopen_lever, minimum=0, hint=" (m)")
        if not (
            is_plain_number(self.time_lag_s)
            and math.isfinite(self.time_lag_s)
            and -MAX_SENSOR_LAG_S <= self.time_lag_s <= MAX_KINEMATICS_LAG_S
        ):
            raise OptionError(
                "time_lag_s",
                f"must be a number of seconds from -{MAX_SENSOR_LAG_S:g} (sensor late) "
                f"to {MAX_KINEMATICS_LAG_S:g} (kinematics late), got {self.time_lag_s!r}",
            )
        text("warm_start", self.warm_start, hint=" (a path)")
        kernel_option(self.kernel)
        mount_matrix(self.mount_rotation_SE, self.mount_R_SE)
        gain_inverse("gain_force_S", self.gain_force_S)
        gain_inverse("gain_torque_S", self.gain_torque_S)
        wrench_bound("max_force", self.max_force, MAX_FORCE)
        wrench_bound("max_torque", self.max_torque, MAX_TORQUE)

    # the options as the estimator runs them: the effects list switches on the options it names

    @property
    def resolved_bias_rate(self) -> bool:
        """bias_rate, or an effect that needs the bias's rate (bias_drift, warm_up)."""
        return self.bias_rate or bool(set(self.effects or []) & {"bias_drift", "warm_up"})

    @property
    def resolved_mount_rotation(self) -> bool:
        """mount_rotation, or the mount_rotation effect."""
        return self.mount_rotation or "mount_rotation" in (self.effects or [])

    @property
    def resolved_inertia(self) -> bool:
        """inertia, or the inertia effect."""
        return self.inertia or "inertia" in (self.effects or [])

    @property
    def resolved_force_tilt_rw(self) -> float | str:
        """bias_force_tilt_rw: "auto" unless the mount is estimated (then 0), as given otherwise."""
        if self.bias_force_tilt_rw is None:
            return 0.0 if self.resolved_mount_rotation else "auto"
        return self.bias_force_tilt_rw


def is_plain_number(value: Any) -> bool:
    """An int or float, not a bool."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def noise_axes(key: str, value: Any) -> np.ndarray:
    """A positive std per axis from one number or three; OptionError naming the option."""
    try:
        array = np.array(value, dtype=float) if not isinstance(value, (bool, str)) else np.array(np.nan)
    except (TypeError, ValueError):
        array = np.array(np.nan)
    if array.ndim == 0:
        array = np.full(3, float(array))
    if array.shape != (3,) or not np.all(np.isfinite(array)) or np.any(array <= 0):
        raise OptionError(key, f"must be a positive number, 3 positive numbers or 'auto', got {value!r}")
    return array


def mount_matrix(rotvec: Any, matrix: Any) -> np.ndarray:
    """R_SE from ``mount_rotation_SE`` (rotation vector, rad) or ``mount_R_SE`` (3x3); identity if neither.

    A matrix must be a rotation: orthonormal with det = +1. A mirrored mount (det = −1, e.g. one axis
    flipped by a wrong sensor configuration) is refused: no rotation can describe it.
    """
    if rotvec is not None and matrix is not None:
        raise OptionError("mount_R_SE", "give the mount either as mount_rotation_SE or as mount_R_SE, not both")
    if rotvec is not None:
        v = np.array(rotvec, dtype=float)
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise OptionError("mount_rotation_SE", f"must be a rotation vector of 3 numbers (rad), got {rotvec!r}")
        return matrix_from_rotvec(v)
    if matrix is None:
        return np.eye(3)
    R = matrix3("mount_R_SE", matrix, "")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6):
        raise OptionError("mount_R_SE", "not orthonormal (Rᵀ R ≠ I to 1e-6); give a rotation matrix")
    det = float(np.linalg.det(R))
    if det < 0:
        raise OptionError(
            "mount_R_SE",
            f"the axes are mirrored (det = {det:.3f}); a sensor mount is a rotation "
            "(det = +1): check the sensor's axis convention (a flipped axis)",
        )
    return R


def matrix3(key: str, value: Any, meaning: str) -> np.ndarray:
    """A finite 3x3 float matrix from an option's value; OptionError naming the option."""
    try:
        M = np.array(value, dtype=float)
    except (TypeError, ValueError):
        M = np.zeros(0)
    if M.shape != (3, 3) or not np.all(np.isfinite(M)):
        raise OptionError(key, f"must be a 3x3 matrix{meaning}, got {value!r}")
    return M


def gain_inverse(key: str, value: Any) -> np.ndarray | None:
    """(I + G)⁻¹ for a configured calibration error G (measured = (I + G)·true), or None."""
    if value is None:
        return None
    G = matrix3(key, value, " (measured = (I + G)·true)")
    smallest = float(np.linalg.svd(np.eye(3) + G, compute_uv=False).min())
    if np.abs(G).max() > 0.5 or smallest < 0.5:
        raise OptionError(
            key,
            f"not a small calibration error (largest entry {np.abs(G).max():.2f}, "
            f"smallest singular value of I + G {smallest:.2f}; expected entries ≤ 0.5 and ≥ 0.5)",
        )
    return np.linalg.inv(np.eye(3) + G)
