"""Each tick's haptic command: the force sent to the trainee's hand, its re-arm button, the robot target it makes.

The primary estimate becomes one force command: the gate (``gate``) says
whether, the governor (``safety.ForceGovernor``) how much. It is sent and
recorded with the device's state; a haptic device that raises is a lost device:
the force is zeroed and the session goes on recording. With ``[teleop]`` on, the
master's state then becomes the robot's next target (``teleop.Teleoperation``),
sent (``servo_cp``) and recorded.

A latched stop (``gate``) holds the force off until an explicit re-arm: a press
of the device's ``haptic.rearm_button`` (an edge: released, then pressed), the
``r`` key of ``hapticlab run``, or :meth:`~.loop.LiveLoop.rearm` (also handed to
status callbacks as ``SessionStatus.rearm``); each is honoured at the next tick.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from hapticlab.core.host.interfaces import HasForceLimit
from hapticlab.core.types import Event, HapticCommand, PoseSample
from hapticlab.sessions.live.build import Session
from hapticlab.sessions.live.gate import HapticGate
from hapticlab.sessions.live.status import SessionStatus
from hapticlab.sessions.live.taps import Taps
from hapticlab.sessions.live.teleop import Teleoperation


class HapticCommander:
    """The trainee's side of one session's loop (built by the loop).

    Attributes:
        governor: how much force, and the zero command (``safety.ForceGovernor``).
        teleop: the robot's targets from the master's state, or None without ``[teleop]``.
        rearm_requests: re-arm requests not yet honoured, by source (``"api"``, ``"key r"``, ``"button 3"``).
        last_estimate: the primary estimator's newest ``(contact_force_S, R_BS, t_ns)``, None before the first.
        last_pose: the newest measured flange pose (what teleoperation starts from).
        haptic_on_ticks: ticks whose command had the force on.
    """

    def __init__(
        self,
        session: Session,
        gate: HapticGate,
        status: SessionStatus,
        on_event: Callable[[Event], None],
        call: Callable[..., Any],
    ):
        """``on_event`` records an event; ``call(part, method, *args)`` calls a device (what it raises ends
        the session, named)."""
        self.s, self.gate, self.status = session, gate, status
        self.on_event, self.call = on_event, call
        self.governor = session.governor()
        self.force_limit = session.haptic if isinstance(session.haptic, HasForceLimit) else None
        self.rearm_bit = session.haptic_settings.rearm_button  # -1: no button
        self.button_down = True  # unknown counts as held: a button held at the start must be released first
        self.rearm_requests: deque[str] = deque()
        self.teleop = Teleoperation(session.teleop_settings, self.governor.R_DB) if session.robot is not None else None
        self.last_pose: PoseSample | None = None
        self.last_estimate: tuple[np.ndarray, np.ndarray, int] | None = None  # (contact_force_S, R_BS, t_ns)
        self.haptic_reason = "starting"
        self.haptic_on_ticks = 0

    def command(self, now_ns: int, taps: Taps) -> None:
        """The tick's force command from the gate's reason and the last estimate: sent, recorded, then the
        robot's target from the device's state."""
        reason = self.gate.reason(now_ns)
        while self.rearm_requests:
            event = self.gate.rearm(now_ns, self.rearm_requests.popleft())
            if event is not None:
                self.on_event(event)
                reason = self.gate.reason(now_ns)
        fault = self.gate.fault_event(reason, now_ns)
        if fault is not None:
            self.on_event(fault)
        if self.force_limit is not None:
            try:
                self.governor.device_max_force = self.force_limit.max_force
            except Exception:  # a device that cannot say its limit now: the governor zeroes a NaN limit
                self.governor.device_max_force = float("nan")
        force_S, R_BS, source_t_ns = self.last_estimate or (None, None, None)
        command = self.governor.command(now_ns, force_S, R_BS, reason=reason, source_t_ns=source_t_ns)
        try:
            self.s.haptic.send(command)
            state = self.s.haptic.state()
        except Exception as exc:  # a lost device: zero is all we can still ask for
            command = self.governor.command(now_ns, None, None, reason=f"device error: {exc}")
            state = None
        taps.command(command)
        if state is not None:
            taps.device_state(state)
        self.watch_button(state)
        if self.teleop is not None:
            self._servo(now_ns, state, command.enabled, taps)
        self.haptic_on_ticks += command.enabled
        if command.reason.split(" (")[0] != self.haptic_reason.split(" (")[0]:  # not each new figure in it
            self.on_event(
                Event(now_ns, "haptic_enabled", "haptic force on")
                if command.enabled
                else Event(now_ns, "haptic_disabled", f"haptic force zeroed: {command.reason}")
            )
            self.haptic_reason = command.reason
        self.status.haptic_enabled, self.status.reason = command.enabled, command.reason
        self.status.latched = self.gate.latched

    def zero(self, end_ns: int, reason: str, taps: Taps) -> HapticCommand:
        """The session's final zero command: sent (an ``error`` event if it cannot be) and recorded."""
        zero = self.governor.command(end_ns, None, None, reason=reason)
        try:
            self.s.haptic.send(zero)
        except Exception as exc:
            self.on_event(Event(end_ns, "error", f"the final zero command could not be sent: {exc}"))
        taps.command(zero)
        return zero

    def _servo(self, now_ns: int, state, haptic_on: bool, taps: Taps) -> None:
        """The robot's next target from the master's state: sent (``servo_cp``) and recorded."""
        assert self.teleop is not None and self.s.robot is not None  # (teleoperation is on)
        target, events = self.teleop.step(now_ns, self.last_pose, state, haptic_on)
        for event in events:
            self.on_event(event)
        if target is not None:
            self.call("kinematics", self.s.robot.servo_cp, target.t_ns, target.R_BE, target.p_BoEo_B)
            taps.robot_target(target)
            self.status.teleop = target.mode if not target.reason else f"{target.mode}: {target.reason}"

    def watch_button(self, state) -> None:
        """A press of the re-arm button (up, then down: a held button counts once) asks for a re-arm."""
        if self.rearm_bit < 0:
            return
        down = True if state is None else bool((int(state.buttons) >> self.rearm_bit) & 1)  # no state: unknown
        if down and not self.button_down and state is not None:
            self.rearm_requests.append(f"button {self.rearm_bit}")
        self.button_down = down
