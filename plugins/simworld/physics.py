"""The simulated world: one rigid tool on a wrist F/T sensor, moved by a simulated robot.

The simulated sensor and the simulated robot of a session both read one
:class:`SimWorld`, so the wrench and the pose always agree.

What the sensor reads
---------------------
The sensor reads the wrench the tool exerts on it. With ``m`` the tool mass,
``c = cog_S`` its centre of mass and ``I = inertia_S`` its inertia about the
centre of mass (all in the sensor frame S), Newton and Euler for the tool give,
about the sensor origin and expressed in S::

    F_read_S = (I + G_f) [m (g_S − a_cm_S) + f_contact_S] + bias_force_S(t) + noise
    τ_read_S = (I + G_t) [c × m (g_S − a_cm_S) + Σ p_contact_S × f_contact_S
               − (I ω̇ + ω × I ω)] + bias_torque_S(t) + noise

with

* ``g_S = R_SE R_EB R_BG [0, 0, −g]`` gravity in S (g = 9.80665 m/s² along −z of G);
* ``ω``, ``ω̇`` the angular velocity and acceleration of S (that is, of E) in B,
  expressed in S: ``ω = R_SE ω_E``;
* ``a_cm_S = a_So_S + ω̇ × c + ω × (ω × c)`` the acceleration of the centre of
  mass, ``a_So`` that of the sensor origin:
  ``a_So_B = a_BEo_B + R_BE (ω̇_E × p_EoSo_E + ω_E × (ω_E × p_EoSo_E))``;
  together (the form evaluated) ``a_cm_S = R_SB a_BEo_B + ω̇ × r + ω × (ω × r)``
  with ``r = R_SE p_EoSo_E + c`` the centre of mass seen from the flange origin.

``G_f``, ``G_t`` are the sensor's calibration errors (``SensorParams.gain_*``,
zero by default). The motion derivatives come analytically from the motion
script (see ``motion/``). With ``inertia=False`` the terms in ``a_cm`` and
``I`` are dropped and (with zero calibration error) the reading is exactly the
paper's model ``S_f = R_SE R_EB B_f + f0``, ``S_τ = c × (S_f − f0) + τ0``.

The robot's kinematics may run on a clock offset from the sensor's
(``RobotParams.kinematics_lag_s``): ``pose(t)`` reports the pose stamped t,
while the wrench always follows the true motion.

What the sensor's channels make of the wrench on them (the calibration error,
hysteresis, bias, noise and saturation) is ``sensor_channels.py``; its random
streams, pure functions of (seed, time), ``randomness.py``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from hapticlab.core.frames import rotvec_from_matrix, skew
from hapticlab.core.types import STATUS_OK, STATUS_SATURATED
from hapticlab.plugins.simworld.cable import Cable
from hapticlab.plugins.simworld.config import WorldSpec, parse_world_table
from hapticlab.plugins.simworld.contacts import Contact
from hapticlab.plugins.simworld.faults import Fault
from hapticlab.plugins.simworld.motion import MotionScript, MotionState, RandomTour
from hapticlab.plugins.simworld.params import RobotParams, SensorParams, ToolParams
from hapticlab.plugins.simworld.rows import apply_rows as _apply
from hapticlab.plugins.simworld.rows import cross_rows as _cross
from hapticlab.plugins.simworld.sensor_channels import SensorChannels
from hapticlab.plugins.simworld.servo import ServoedMotion
from hapticlab.plugins.simworld.tissue import Tissue

__all__ = ["SimWorld"]


def _times(t: float | np.ndarray) -> np.ndarray:
    return np.atleast_1d(np.asarray(t, dtype=float)).ravel()


# --------------------------------------------------------------------------- the world


class SimWorld:
    """One physical model behind the simulated F/T sensor and the simulated robot.

    Parameters
    ----------
    tool, sensor, robot : the physical parameters (defaults: a 0.35 kg surgical
        instrument on an ATI Gamma class sensor, base tilted by [0.02, −0.01, 0] rad).
    motion : the robot's motion script (default: a RandomTour from ``seed``
        around ``robot.p_BoEo_B``).
    contacts : contact events (Indentation, HangingMass).
    seed : seed of every random stream (noise, drift, motion).
    inertia : include the tool's inertial wrench (False: the paper's static model).
    """

    def __init__(
        self,
        tool: ToolParams | None = None,
        sensor: SensorParams | None = None,
        robot: RobotParams | None = None,
        motion: MotionScript | None = None,
        contacts: Iterable[Contact] = (),
        seed: int = 1,
        inertia: bool = True,
        faults: Iterable[Fault] = (),
    ):
        self.tool = tool if tool is not None else ToolParams()
        self.sensor = sensor if sensor is not None else SensorParams()
        self.robot = robot if robot is not None else RobotParams()
        self.seed = int(seed)
        self.motion = motion if motion is not None else RandomTour(seed=self.seed, p_BoEo_B=self.robot.p_BoEo_B)
        self.contacts = tuple(contacts)
        self.faults = tuple(faults)
        """Injected faults (``faults.py``): the sim sensor and kinematics apply them to what they deliver."""
        self.inertia = bool(inertia)
        self.R_SE = self.sensor.R_SE
        self.R_BG = self.robot.R_BG
        self.gravity_accel_B = self.robot.gravity_accel_B
        self._init_wrench_constants()
        self._last_forces: tuple[MotionState, list[np.ndarray]] | None = None
        self.channels = SensorChannels(self.sensor, self.seed, lambda t: self._loaded(t, False)[1], ahead=not self.live)
        """What the sensor's channels make of the wrench on them (``sensor_channels.py``)."""

    def _init_wrench_constants(self) -> None:
        """Everything wrench() needs that does not change, computed once.

        The live loop asks for one to seven samples at a time, so a read costs the
        number of numpy calls rather than their size: every constant product is
        folded into one matrix here, every cross product with a constant vector
        is a matrix (``c × v = [c]× v``), and per read each matrix is applied
        once (see ``rows.apply_rows``).
        """
        tool, sensor, R_SE = self.tool, self.sensor, self.R_SE
        self._weight_B = tool.mass * self.gravity_accel_B
        """(3,) the tool's weight in B, N."""
        self._cog_cross_S = skew(tool.cog_S)
        """(3, 3) ``[c]×``: ``c × v == _apply(self._cog_cross_S, v)``."""
        by_point: dict[tuple[float, ...], list[Contact]] = {}
        for event in self.contacts:
            point_S = tool.tip_S if event.point_S is None else event.point_S
            by_point.setdefault(tuple(point_S), []).append(event)
        self._contacts_by_point = [
            (skew(np.array(point_S)), self.sensor.p_EoSo_E + R_SE.T @ np.array(point_S), events)
            for point_S, events in by_point.items()
        ]
        """The contacts grouped by where they act: ``([p]× (3, 3), p_EoP_E (3,), events)`` per point p
        (in S, m; ``p_EoP_E`` the point from the flange origin, in E, m), so that the forces at one
        point are rotated and crossed once."""
        self._minus_lever_cross_E = [skew(-p_EoP_E) for _, p_EoP_E, _ in self._contacts_by_point]
        """(3, 3) ``[−p_EoP_E]×`` per point: ``ω × p == _apply(it, ω)``."""
        # The rotational terms of the inertial wrench as maps of the flange's angular
        # motion in E, with ω = R_SE ω_E (in S) and r the centre of mass from the flange
        # origin: [ω̇ × r, I ω̇] is linear in ω̇_E, and [ω × (ω × r), ω × I ω] is linear in
        # the products ω_Ej ω_Ek: Σ_jk ω_Ej ω_Ek · e_j × (e_k × r) with e_j the E axes in S.
        r = R_SE @ sensor.p_EoSo_E + tool.cog_S  # p_EoCm_S, m
        self._alpha_map = np.concatenate([skew(r).T @ R_SE, tool.inertia_S @ R_SE])
        """(6, 3): ``_apply(self._alpha_map, ω̇_E) == [ω̇ × r, I ω̇]`` (in S)."""
        e_j, e_k = R_SE.T[:, None, :], R_SE.T[None, :, :]  # the E axes in S, (3, 1, 3) and (1, 3, 3)
        centripetal = np.cross(e_j, np.cross(e_k, r))  # [j, k]: e_j × (e_k × r)
        gyroscopic = np.cross(e_j, e_k @ tool.inertia_S.T)  # [j, k]: e_j × I e_k
        self._w_products_map = np.concatenate([centripetal, gyroscopic], axis=2).reshape(9, 6).T
        """(6, 9): ``_apply(self._w_products_map, (ω_E ω_Eᵀ).ravel()) == [ω × (ω × r), ω × I ω]`` (in S)."""

    @classmethod
    def from_config(cls, table: Mapping[str, Any] | None) -> SimWorld:
        """Build from a session's ``[world]`` table (keys in ``docs/sessions.md``, read by ``config.py``).

        Raises
        ------
        hapticlab.core.host.registry.ConfigError
            On an unknown key or a wrong value, naming the full key.
        """
        return cls.from_spec(parse_world_table(table))

    @classmethod
    def from_spec(cls, spec: WorldSpec) -> SimWorld:
        """Build from a parsed WorldSpec."""
        return cls(
            tool=spec.tool,
            sensor=spec.sensor,
            robot=spec.robot,
            motion=spec.motion,
            contacts=spec.contacts,
            seed=spec.seed,
            inertia=spec.inertia,
            faults=spec.faults,
        )

    # ---------------------------------------------------------------- kinematics

    def motion_state(self, t: float | np.ndarray) -> MotionState:
        """Flange pose and its analytic derivatives at times ``t`` (s)."""
        return self.motion.evaluate(t)

    @property
    def live(self) -> bool:
        """True when the robot follows targets sent while the session runs (``servo``): the world is
        only known up to now, so the simulated devices must not compute ahead."""
        return isinstance(self.motion, ServoedMotion)

    def servo_cp(self, t: float, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None:
        """Send the robot a flange target from world time ``t`` (s) on: ``R_BE`` (3, 3), ``p_BoEo_B`` (3,) m.

        Only a world whose motion is ``servo`` follows targets; any other raises TypeError.
        """
        if not isinstance(self.motion, ServoedMotion):
            raise TypeError(
                f"the simulated robot follows a scripted motion ({self.motion.name!r}), not targets; "
                f'set [world.motion] script = "servo"'
            )
        self.motion.servo_cp(t, R_BE, p_BoEo_B)

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R_BE (N, 3, 3), p_BoEo_B (N, 3))``: the flange pose the kinematics report for stamps ``t`` (s), m.

        With ``robot.kinematics_lag_s`` = τ the pose stamped t is the true pose
        at t − τ (τ > 0: the kinematics stream is late); with τ = 0 (the
        default) it is the true pose at t.
        """
        lag = self.robot.kinematics_lag_s
        state = self.motion.evaluate(t if lag == 0.0 else _times(t) - lag)
        return state.R_BE, state.p_BoEo_B

    # ---------------------------------------------------------------- sensor

    def bias(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """True sensor bias at times ``t`` (s): ``(bias_force_S (N, 3) N, bias_torque_S (N, 3) N·m)``."""
        bias_S = self.channels.bias(_times(t))
        return bias_S[:, :3], bias_S[:, 3:]

    def wrench(
        self,
        t: float | np.ndarray,
        noise: bool = True,
        known: tuple[np.ndarray, np.ndarray] | None = None,
        truth: bool = True,
    ) -> dict[str, np.ndarray]:
        """The sensor reading at times ``t`` (s), with the truth behind it.

        Parameters
        ----------
        t : scalar or (N,) times, s (world time: 0 when the session starts).
        noise : add the sensor's white noise (bias, drift and saturation always apply).
        known : the channels' bias and noise at ``t``, (N, 6) each, when already computed
            (``SensorChannels.read``: they are functions of time alone).
        truth : False: no ``contact`` flag, angular velocity or acceleration (what a live read skips).

        Returns
        -------
        dict of arrays, all in S unless named otherwise:
            ``force_S`` (N, 3) N and ``torque_S`` (N, 3) N·m: what the sensor reads
            (clipped at saturation); ``status`` (N,) int: STATUS_SATURATED where any
            axis went beyond its range, else STATUS_OK; ``contact`` (N,) bool: a
            contact force is acting; ``contact_force_S``, ``contact_torque_S``
            (N, 3): the true contact wrench (torque about the sensor origin);
            ``gravity_force_S``, ``gravity_torque_S``: the tool's weight and its
            moment; ``inertial_force_S`` = −m a_cm_S and ``inertial_torque_S`` =
            c × (−m a_cm_S) − (I ω̇ + ω × I ω) (zero with inertia off);
            ``bias_force_S``, ``bias_torque_S``: the true bias at t;
            ``angular_velocity_S`` (rad/s), ``angular_acceleration_S`` (rad/s²);
            ``R_EB`` (N, 3, 3); ``p_BoEo_B`` (N, 3) m; ``t`` (N,) s.
        """
        t = _times(t)
        parts, load_S = self._loaded(t, truth)
        # What the sensor reads, force then torque side by side: (N, 6)
        reading_S, bias_S, saturated = self.channels.read(t, load_S, noise, known)
        parts.update(
            {
                "force_S": reading_S[:, :3],
                "torque_S": reading_S[:, 3:],
                "status": np.where(saturated, STATUS_SATURATED, STATUS_OK).astype(np.int64),
                "bias_force_S": bias_S[:, :3],
                "bias_torque_S": bias_S[:, 3:],
            }
        )
        return parts

    def _loaded(self, t: np.ndarray, truth: bool = True) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The true wrench at times ``t`` (N,) s, by part (see :meth:`wrench`, and its ``truth``), and the load
        the sensor's channels see, (N, 6) force (N) then torque (N·m): the sum, after the calibration error."""
        n = len(t)
        tool = self.tool
        state = self.motion.evaluate(t)
        R_EB = state.R_BE.transpose(0, 2, 1)
        R_SB = self.R_SE @ R_EB

        gravity_force_S = _apply(R_SB, self._weight_B)
        gravity_torque_S = _apply(self._cog_cross_S, gravity_force_S)  # c × m g_S

        w_E, alpha_E = state.w_BE_E, state.alpha_BE_E
        if self.inertia:
            # [ω̇ × r + ω × (ω × r), I ω̇ + ω × I ω] (N, 6), r the centre of mass from the flange origin
            w_products_E = (w_E[:, :, None] * w_E[:, None, :]).reshape(n, 9)  # ω_Ej ω_Ek
            rotational = _apply(self._alpha_map, alpha_E) + _apply(self._w_products_map, w_products_E)
            a_cm_S = _apply(R_SB, state.a_BEo_B) + rotational[:, :3]
            inertial_force_S = -tool.mass * a_cm_S
            euler_S = rotational[:, 3:]  # I ω̇ + ω × I ω
            inertial_torque_S = _apply(self._cog_cross_S, inertial_force_S) - euler_S
        else:
            inertial_force_S = np.zeros((n, 3))
            inertial_torque_S = np.zeros((n, 3))

        contact_force_S = np.zeros((n, 3))
        contact_torque_S = np.zeros((n, 3))
        for (point_cross_S, _, _), force_B in zip(self._contacts_by_point, self._contact_forces_B(t, state)):
            force_S = _apply(R_SB, force_B)
            contact_force_S += force_S
            contact_torque_S += _apply(point_cross_S, force_S)  # p × f

        reading_S = np.empty((n, 6))
        reading_S[:, :3] = gravity_force_S + inertial_force_S + contact_force_S
        reading_S[:, 3:] = gravity_torque_S + inertial_torque_S + contact_torque_S
        reading_S = self.channels.calibrated(reading_S)
        parts = {
            "t": t,
            "contact_force_S": contact_force_S,
            "contact_torque_S": contact_torque_S,
            "gravity_force_S": gravity_force_S,
            "gravity_torque_S": gravity_torque_S,
            "inertial_force_S": inertial_force_S,
            "inertial_torque_S": inertial_torque_S,
            "R_EB": R_EB,
            "p_BoEo_B": state.p_BoEo_B,
        }
        if truth:
            parts["contact"] = (contact_force_S != 0.0).any(axis=1) if self.contacts else np.zeros(n, dtype=bool)
            parts["angular_velocity_S"] = _apply(self.R_SE, w_E)
            parts["angular_acceleration_S"] = _apply(self.R_SE, alpha_E)
        return parts, reading_S

    def _contact_forces_B(self, t: np.ndarray, state: MotionState) -> list[np.ndarray]:
        """The contact force at each point of ``_contacts_by_point`` at times ``t`` (N,) s, (N, 3) N in B each.

        The same ``state`` object asked for again (a servoed motion's, for the sensor and the robot of one
        tick) gets the same forces back, not recomputed (to be read, never written)."""
        last = self._last_forces  # (one read: another thread may replace it)
        if last is not None and last[0] is state:
            return last[1]
        forces = self._contact_forces_at(t, state)
        self._last_forces = (state, forces)
        return forces

    def _contact_forces_at(self, t: np.ndarray, state: MotionState) -> list[np.ndarray]:
        forces = []
        for (_, p_EoP_E, events), minus_lever_cross_E in zip(self._contacts_by_point, self._minus_lever_cross_E):
            force_B = np.zeros((len(t), 3))
            for event in events:
                if isinstance(event, (Tissue, Cable)):  # a reaction to where the point is and how it moves, in B
                    r_B = _apply(state.R_BE, p_EoP_E)
                    x_B = state.p_BoEo_B + r_B
                    v_B = state.v_BEo_B + _apply(state.R_BE, _apply(minus_lever_cross_E, state.w_BE_E))  # ω × p
                    force_B += event.force_B_at(x_B, v_B)
                else:
                    force_B += event.force_B(t, self.gravity_accel_B)
            forces.append(force_B)
        return forces

    def contact_wrench_B(self, t: float | np.ndarray) -> np.ndarray:
        """The true contact wrench on the tool at times ``t`` (s), in B: (N, 6), the force (N) then its moment
        about the flange origin E (N·m). What a robot that measures its own wrench (a UR's
        ``actual_TCP_force``, the TCP at the flange) would report without error."""
        t = _times(t)
        state = self.motion.evaluate(t)
        wrench_B = np.zeros((len(t), 6))
        for (_, p_EoP_E, _), force_B in zip(self._contacts_by_point, self._contact_forces_B(t, state)):
            wrench_B[:, :3] += force_B
            wrench_B[:, 3:] += _cross(_apply(state.R_BE, p_EoP_E), force_B)  # r × f
        return wrench_B

    # ---------------------------------------------------------------- truth

    def truth(self, t: float | np.ndarray | None = None) -> dict[str, Any]:
        """The true parameters, named as in the paper's model and the estimators' ``params()``.

        ``S_f = R_SE R_EB gravity_force_B + bias_force_S`` and
        ``S_τ = cog_S × (S_f − bias_force_S) + bias_torque_S`` (no contact, no inertia).

        Parameters
        ----------
        t : time (s) for the drifting biases: None means t = 0; a scalar gives
            (3,) biases, an array (N, 3).

        Returns
        -------
        dict: ``gravity_force_B`` (3,) N (= R_BG [0, 0, −m g]); ``bias_force_S`` N;
        ``cog_S`` (3,) m; ``bias_torque_S`` N·m; ``mount_rotation_SE`` (3,)
        rotation vector of R_SE, rad; ``mass_kg``; and, for completeness,
        ``base_tilt_BG`` (rad), ``p_EoSo_E`` (m), ``inertia_S`` (kg·m²), ``tip_S`` (m),
        ``gain_force_S``, ``gain_torque_S`` (3, 3) and ``kinematics_lag_s`` (s).
        """
        bias_force_S, bias_torque_S = self.bias(0.0 if t is None else t)
        if t is None or np.ndim(t) == 0:
            bias_force_S, bias_torque_S = bias_force_S[0], bias_torque_S[0]
        return {
            "gravity_force_B": self.tool.mass * self.gravity_accel_B,
            "bias_force_S": bias_force_S,
            "cog_S": self.tool.cog_S.copy(),
            "bias_torque_S": bias_torque_S,
            "mount_rotation_SE": rotvec_from_matrix(self.R_SE),
            "mass_kg": self.tool.mass,
            "base_tilt_BG": self.robot.base_tilt_BG.copy(),
            "p_EoSo_E": self.sensor.p_EoSo_E.copy(),
            "inertia_S": self.tool.inertia_S.copy(),
            "tip_S": self.tool.tip_S.copy(),
            "gain_force_S": self.sensor.gain_force_S.copy(),
            "gain_torque_S": self.sensor.gain_torque_S.copy(),
            "kinematics_lag_s": self.robot.kinematics_lag_s,
        }
