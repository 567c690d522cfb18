"""Teleoperation: the master's handle moves the robot's flange; the contact comes back as force.

Once per loop tick, after the force command, :meth:`Teleoperation.step` turns
the master's state into a target for the robot (a ``RobotTarget``, sent with
the robot's ``servo_cp`` and recorded on ``/robot/target``). It runs in two
phases:

1. **calibrating**: from where the robot stands when the session starts, it
   visits tilted and rolled orientations (``calibration_tilt_deg``, holding
   each for ``calibration_dwell_s`` once reached) and comes back. A tool held at
   one orientation never shows the estimator its weight from more than one
   side, so the haptic force would never come on; this is the identification
   motion the paper runs before the contact task. The tilts turn about the
   flange, which lifts the tool tip: a tour started just above tissue does not
   touch it. The tour only advances while the master reports a fresh state (a
   person at the console); without one the robot holds.
2. **following** while the trainee may drive the robot, **holding** otherwise,
   with the reason: the clutch button is pressed (the hand repositions on the
   master without moving the robot), the master or the robot has been silent
   for more than ``WATCHDOG_NS`` (a lost device or link: the force is zeroed
   too), or the haptic force is off (``require_haptics``: the trainee must
   feel what the tool touches while moving it). After a silent channel the
   robot waits for the handle to come back to where it left (``REENGAGE_M``),
   or for a clutch press, before it follows again.

Following: each time it (re-)engages, the offset between hand and robot is
captured, so the robot never jumps: with ``p_engaged`` the target then and
``h_engaged`` the handle position then (in the device base D)::

    p_target = p_engaged + scale · R_BD (h − h_engaged)

``R_BD`` is the transpose of the haptic mapping's ``R_DB``: pushing the handle
along a direction moves the tool along it, and a contact force against that
motion comes back against the hand. The target is then kept within
``workspace_radius`` of where the robot started and moves at most
``max_speed`` (m/s) per tick; the orientation is held (3-DoF masters have none).

The target never jumps, in the tour either: its orientation turns towards the
goal at most ``max_angular_speed`` (rad/s), its position moves at most
``max_speed``, so a robot that servos to each target as it comes (a UR's
``servoj``) is never asked for more than those speeds.
"""

from __future__ import annotations

import math
import re

import numpy as np

from hapticlab.core.frames import matrix_from_quat_wxyz, matrix_from_rotvec, rotvec_from_matrix
from hapticlab.core.types import DeviceState, Event, PoseSample, RobotTarget
from hapticlab.sessions.settings import TeleopSettings

WATCHDOG_NS = 30_000_000
"""A master state or a robot pose older than this (ns) is a silent channel: the robot holds and the force goes to
zero. The dVRK's watchdog (``io.watchdog-timeout``, 30 ms by default in ``mtsIntuitiveResearchKit.h``): three
periods of a 100 Hz link, thirty of a 1 kHz one, so a late packet is not a lost device."""
REENGAGE_M = 0.01
"""After a silent channel the robot follows again only once the handle is back within this distance (m) of where
it was when the channel went silent (or after a clutch press): the hand and the tool keep their correspondence, and
a robot never starts moving again on a hand that has gone elsewhere."""
MAX_HANDLE_M = 1.0
"""A handle reported farther than this from the device's origin (m) is no hand's: the robot holds. Desktop
masters reach 0.1-0.4 m (Haply Inverse3: a ~0.4 m sphere), so 1 m leaves any real device its whole workspace."""
TOUR_ROLL_RAD = math.pi / 3
"""The calibration tour's roll about the tool's axis, rad (±60°)."""


def reason_kind(reason: str) -> str:
    """A reason without its details in brackets and its figures: a stream 31 ms old and one 32 ms old are one hold,
    one event (the haptic command's reasons are compared so too)."""
    return re.sub(r"[0-9.]+", "#", reason.split(" (")[0])


def calibration_tour(R_BE_0: np.ndarray, tilt_deg: float) -> list[np.ndarray]:
    """The orientations the robot visits before teleoperation, each (3, 3), ending where it began.

    Tilts about B's x and y axes (through the flange), two of them with the tool also
    rolled ±60° about its own axis, so gravity is seen along every axis of the sensor.
    """
    if tilt_deg <= 0:
        return []
    tilt = math.radians(tilt_deg)

    def about_B(axis, angle):
        return matrix_from_rotvec(np.asarray(axis, dtype=float) * angle)

    def roll(angle):
        return matrix_from_rotvec(np.array([0.0, 0.0, angle]))

    return [
        about_B([1, 0, 0], tilt) @ R_BE_0,
        about_B([1, 0, 0], tilt) @ R_BE_0 @ roll(TOUR_ROLL_RAD),
        about_B([0, 1, 0], tilt) @ R_BE_0,
        about_B([1, 0, 0], -tilt) @ R_BE_0 @ roll(-TOUR_ROLL_RAD),
        about_B([0, 1, 0], -tilt) @ R_BE_0,
        R_BE_0,
    ]


class Teleoperation:
    """Master handle → robot flange target, with clutch, offset, speed limit and workspace bound.

    Args:
        settings: the ``[teleop]`` table.
        R_DB: (3, 3) orientation of the robot base B in the device base D (``haptic.rotation_DB``).

    Attributes:
        mode: ``"waiting"`` (no robot pose yet), ``"calibrating"``, ``"following"`` or ``"holding"``.
        reason: why it is holding ("" otherwise).
        start: ``(R_BE (3, 3), p_BoEo_B (3,) m)`` where the robot stood at the first pose.
    """

    def __init__(self, settings: TeleopSettings, R_DB: np.ndarray):
        self.settings = settings
        self.R_BD = np.asarray(R_DB, dtype=float).T
        self.mode, self.reason = "waiting", ""
        self.start: tuple[np.ndarray, np.ndarray] | None = None
        self.tour: list[np.ndarray] = []
        self.tour_index = 0
        self.reached_ns: int | None = None  # when the tour's current orientation was reached
        self.p_target = np.zeros(3)
        self.R_target = np.eye(3)
        self.engaged: tuple[np.ndarray, np.ndarray] | None = None  # (p_engaged, h_engaged)
        self.handle: np.ndarray | None = None  # the handle at the last tick the robot followed it, m in D (None:
        # no hand-tool correspondence to keep: not yet followed, or re-anchored by the clutch)
        self.left_at: np.ndarray | None = None  # where the handle was when a channel went silent, m in D
        self.last_ns: int | None = None

    def step(
        self, now_ns: int, pose: PoseSample | None, state: DeviceState | None, haptic_on: bool
    ) -> tuple[RobotTarget | None, list[Event]]:
        """This tick's target (None until the robot's pose is known) and the events of a change of mode.

        Args:
            now_ns: the tick's time, ns.
            pose: the newest measured flange pose (None before the first).
            state: the master's latest state (None: the device reports none, or is lost).
            haptic_on: the haptic force is on this tick (the trainee feels the contact).
        """
        events: list[Event] = []
        if self.start is None:
            if pose is None:
                return None, events
            R_BE_0 = matrix_from_quat_wxyz(np.asarray(pose.quat_BE, dtype=float))
            p_0 = np.asarray(pose.p_BoEo_B if pose.p_BoEo_B is not None else np.zeros(3), dtype=float)
            self.start = (R_BE_0, p_0.copy())
            self.R_target, self.p_target = R_BE_0, p_0.copy()
            self.tour = calibration_tour(R_BE_0, self.settings.calibration_tilt_deg)
            if self.tour:
                self.mode = "calibrating"
                events.append(
                    Event(
                        now_ns,
                        "teleop_calibrating",
                        f"calibration tour: {len(self.tour)} orientations, each held "
                        f"{self.settings.calibration_dwell_s:g} s, before the hand takes over",
                    )
                )
            else:
                self.mode = "holding"
        dt_s = 0.0 if self.last_ns is None else max(now_ns - self.last_ns, 0) * 1e-9
        self.last_ns = now_ns
        if self.mode == "calibrating":
            return self._tour(now_ns, pose, state, dt_s, events), events
        reason = self._hold_reason(now_ns, pose, state, haptic_on)
        if reason:
            if self.mode != "holding" or reason_kind(reason) != reason_kind(self.reason):  # (not each new figure in it)
                events.append(Event(now_ns, "teleop_holding", f"robot holding: {reason}", {"reason": reason}))
            self.mode, self.reason, self.engaged = "holding", reason, None
            return self._target(now_ns, "holding", reason), events
        assert state is not None  # no hold reason: the master reports a fresh state
        handle = np.asarray(state.p_DoHo_D, dtype=float)
        if self.engaged is None:  # (re-)engaging: the offset is captured, nothing jumps
            self.engaged = (self.p_target.copy(), handle.copy())
            events.append(Event(now_ns, "teleop_following", "robot following the handle"))
        self.mode, self.reason, self.handle = "following", "", handle
        p_engaged, h_engaged = self.engaged
        desired = p_engaged + self.settings.scale * (self.R_BD @ (handle - h_engaged))
        offset = desired - self.start[1]  # the workspace: a ball about where the robot started
        distance = float(np.linalg.norm(offset))
        if distance > self.settings.workspace_radius:
            desired = self.start[1] + offset * (self.settings.workspace_radius / distance)
        step = desired - self.p_target
        step_norm = float(np.linalg.norm(step))
        max_step = self.settings.max_speed * dt_s
        if step_norm > max_step:
            step = step * (max_step / step_norm)
        self.p_target = self.p_target + step
        self._turn(self.start[0], dt_s)  # back to the start orientation, should anything have turned it
        return self._target(now_ns, "following"), events

    def _tour(
        self, now_ns: int, pose: PoseSample | None, state: DeviceState | None, dt_s: float, events: list[Event]
    ) -> RobotTarget:
        """The calibration tour's target: towards the current orientation, held ``calibration_dwell_s`` once
        there, then the next; paused (holding its target) while no person is at the master or the robot is
        silent."""
        absent = self.absent(now_ns, state) or self._silent_robot(now_ns, pose)
        if absent:
            if reason_kind(self.reason) != reason_kind(absent):
                events.append(Event(now_ns, "teleop_holding", f"calibration tour paused: {absent}", {"reason": absent}))
            self.reason, self.reached_ns = absent, None
            return self._target(now_ns, "calibrating", absent)
        if self.reason:
            events.append(Event(now_ns, "teleop_calibrating", "calibration tour resumed"))
            self.reason = ""
        if self._turn(self.tour[self.tour_index], dt_s):
            if self.reached_ns is None:
                self.reached_ns = now_ns
            elif (now_ns - self.reached_ns) * 1e-9 >= self.settings.calibration_dwell_s:
                self.tour_index, self.reached_ns = self.tour_index + 1, None
                if self.tour_index == len(self.tour):
                    self.mode = "holding"
                    events.append(Event(now_ns, "teleop_calibrated", "calibration tour done; the hand takes over"))
        return self._target(now_ns, "calibrating")

    def _turn(self, goal: np.ndarray, dt_s: float) -> bool:
        """Turn the target's orientation towards ``goal`` by at most ``max_angular_speed``·dt; True once there."""
        if self.R_target is goal:
            return True
        delta = rotvec_from_matrix(self.R_target.T @ goal)
        angle = float(np.linalg.norm(delta))
        if angle < 1e-9:
            return True
        largest = self.settings.max_angular_speed * dt_s
        if angle <= largest:
            self.R_target = goal
            return True
        self.R_target = self.R_target @ matrix_from_rotvec(delta * (largest / angle))
        return False

    def _target(self, now_ns: int, mode: str, reason: str = "") -> RobotTarget:
        return RobotTarget(now_ns, self.R_target, self.p_target.copy(), mode, reason)

    def absent(self, now_ns: int, state: DeviceState | None) -> str:
        """Why no person is known to be at the master ("" when the master reports a fresh, finite state)."""
        if state is None:
            return "no state from the master device"
        if now_ns - state.t_ns > WATCHDOG_NS:
            return f"the master's state is {(now_ns - state.t_ns) * 1e-6:.0f} ms old"
        if not np.all(np.isfinite(state.p_DoHo_D)):
            return "the master reports a non-finite handle position"
        distance = float(np.linalg.norm(state.p_DoHo_D))
        if distance > MAX_HANDLE_M:
            return f"the master reports its handle {distance:.3g} m from its origin (more than {MAX_HANDLE_M:g} m)"
        return ""

    @staticmethod
    def _silent_robot(now_ns: int, pose: PoseSample | None) -> str:
        """Why the robot's own stream is not trusted to be live ("" when its newest pose is fresh)."""
        if pose is not None and now_ns - pose.t_ns > WATCHDOG_NS:
            return f"no pose from the robot for {(now_ns - pose.t_ns) * 1e-6:.0f} ms"
        return ""

    def _hold_reason(self, now_ns: int, pose: PoseSample | None, state: DeviceState | None, haptic_on: bool) -> str:
        """Why the robot must not follow the hand now ("" when it may)."""
        silent = self.absent(now_ns, state) or self._silent_robot(now_ns, pose)
        if silent:
            if self.left_at is None and self.handle is not None:  # (holding already or not: the last followed)
                self.left_at = self.handle.copy()
            return silent
        assert state is not None  # not absent: the master reports a state
        bit = self.settings.clutch_button
        if bit >= 0 and (int(state.buttons) >> bit) & 1:
            self.left_at = self.handle = None  # the trainee repositions on purpose: the clutch re-anchors the hand
            return "clutch pressed"
        if self.settings.require_haptics and not haptic_on:
            return "haptic force off"
        if self.left_at is not None:
            away = float(np.linalg.norm(np.asarray(state.p_DoHo_D, dtype=float) - self.left_at))
            if away > REENGAGE_M:
                clutch = " or press the clutch" if bit >= 0 else ""
                return (
                    f"after a silent channel: bring the handle back to where it left ({away * 1e3:.0f} mm away, "
                    f"within {REENGAGE_M * 1e3:.0f} mm){clutch}"
                )
            self.left_at = None
        return ""
