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
So is a tare (``tare``): the device's ``haptic.tare_button``, the ``t`` key, or
:meth:`~.loop.LiveLoop.tare`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from hapticlab.core.host.interfaces import HasForceLimit, Reidentifies
from hapticlab.core.types import DeviceState, Event, HapticCommand, PoseSample
from hapticlab.sessions.live.build import Session
from hapticlab.sessions.live.ending import ToolSnapshot, snapshot
from hapticlab.sessions.live.gate import HapticGate
from hapticlab.sessions.live.passivity import PassivityController
from hapticlab.sessions.live.status import SessionStatus
from hapticlab.sessions.live.taps import Taps
from hapticlab.sessions.live.tare import Tare
from hapticlab.sessions.live.teleop import Teleoperation, reason_kind
from hapticlab.sessions.tools import ToolLibrary, ToolPlan, change_tool_plan


class HapticCommander:
    """The trainee's side of one session's loop (built by the loop).

    Attributes:
        governor: how much force, and the zero command (``safety.ForceGovernor``).
        teleop: the robot's targets from the master's state, or None without ``[teleop]``.
        rearm_requests: re-arm requests not yet honoured, by source (``"api"``, ``"key r"``, ``"button 3"``).
        tare: the sensor's zero and the tare requests not yet honoured (``tare.Tare``).
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
        self.tare_bit = session.haptic_settings.tare_button  # -1: no button
        self.button_down = {self.rearm_bit: True, self.tare_bit: True}  # unknown counts as held: a button held
        # at the start must be released first
        self.tare = Tare()
        self.rearm_requests: deque[str] = deque()
        self.tool_changes: deque[tuple[ToolPlan, dict | None, str]] = deque()  # (new tool, its state, by whom)
        self.changed_from: list[ToolSnapshot] = []  # the named tools changed from, as they were then
        self.teleop = Teleoperation(session.teleop_settings, self.governor.R_DB) if session.robot is not None else None
        self.last_pose: PoseSample | None = None
        self.last_estimate: tuple[np.ndarray, np.ndarray, int] | None = None  # (contact_force_S, R_BS, t_ns)
        self.haptic_reason = "starting"
        self.haptic_on_ticks = 0
        teleop = session.teleop_settings
        self.delay_ns = round(teleop.delay_s * 1e9) if self.teleop is not None else 0
        self.in_flight: deque[tuple[int, tuple]] = deque()  # the governor's inputs on the link to the master
        self.states_in_flight: deque[DeviceState] = deque()  # and the master's states on their way back
        self.arrived: tuple | None = None  # the newest inputs the master has received
        self.passivity = (
            PassivityController(teleop.max_damping, teleop.passivity == "on") if self.teleop is not None else None
        )
        self.last_state: DeviceState | None = None  # the master's newest state, where it is (no delay)
        self.fresh_state: DeviceState | None = None  # and its newest that was not None
        self.last_sent_ns: int | None = None

    def request_tool_change(self, name: str, source: str) -> None:
        """A told tool change, from any thread: the new tool's record and saved state are read here, in the
        caller's thread (a bad one is the caller's error, never the tick's); the next tick takes it."""
        plan = change_tool_plan(self.s.tool, name)
        takes_state = callable(getattr(self.s.primary.estimator, "load_state", None)) and plan.record is not None
        state = ToolLibrary(plan.library).read_state(plan.name) if takes_state else None
        self.tool_changes.append((plan, state, source))

    def _change_tool(self, now_ns: int, plan: ToolPlan, state: dict | None, source: str) -> list[Event]:
        """A told tool change: the primary given the new tool's saved state (when the library had one), the
        gate told (``HapticGate.change_tool``); a state the estimator refuses leaves it to re-identify."""
        events, warm = [], False
        if self.s.tool.name:  # the tool it changed from, as it was: saved to its library at the end (``ending``)
            held = self.gate.reason(now_ns)
            params = self.tare.own(self.call("estimator", self.s.primary.params) or {})  # (in the sensor's own zero)
            self.changed_from.append(snapshot(self.s, params, held, "at the change", tared=self.tare.active))
        if state is not None and self.tare.active:  # (its biases are the sensor's own: the zero would be rendered)
            message = f"tool {plan.name!r}: its saved state not loaded (a tare moved the sensor's zero): identified "
            events.append(Event(now_ns, "tool_state_not_loaded", message + "from the motion"))
        elif state is not None:
            try:
                self.s.primary.estimator.load_state(state)  # type: ignore[attr-defined]
                warm = True
            except Exception as exc:  # (a state of another estimator, or of another version)
                message = f"tool {plan.name!r}: its saved state not loaded ({exc}): identified from the motion"
                events.append(Event(now_ns, "tool_state_not_loaded", message))
        self.s.tool = plan
        what = f"tool {plan.name!r}" if plan.name else "an unnamed tool"
        known = " (known: its saved state loaded)" if warm else " (identified from the motion)"
        return events + self.gate.change_tool(now_ns, f"tool changed by {source} to {what}{known}", warm)

    def command(self, now_ns: int, taps: Taps) -> None:
        """The tick's force command from the gate's reason and the last estimate: sent, recorded, then the
        robot's target from the device's state."""
        reason = self.gate.reason(now_ns)
        while self.rearm_requests:
            event = self.gate.rearm(now_ns, self.rearm_requests.popleft())
            if event is not None:
                self.on_event(event)
                reason = self.gate.reason(now_ns)
        if self.tare.requests or self.tare.collecting:
            for event in self.tare.honour(now_ns, self.gate):
                self.on_event(event)
                if event.kind == "sensor_tared":
                    self._shadows_tared()
            reason = self.gate.reason(now_ns)
        while self.tool_changes:
            for event in self._change_tool(now_ns, *self.tool_changes.popleft()):
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
        if self.passivity is None:
            command = self.governor.command(now_ns, force_S, R_BS, reason=reason, source_t_ns=source_t_ns)
        else:
            command = self._at_the_master(now_ns, (force_S, R_BS, source_t_ns, reason), self._silent_master(now_ns))
        try:
            self.s.haptic.send(command)
            state = self.s.haptic.state()
        except Exception as exc:  # a lost device: zero is all we can still ask for
            command = self.governor.command(now_ns, None, None, reason=f"device error: {exc}")
            state = None
        taps.command(command, None if force_S is None else float(np.linalg.norm(force_S)), self.status.contact)
        if state is not None:
            taps.device_state(state)
        self.watch_button(state)
        if self.teleop is not None:
            self.last_state = state
            self.fresh_state = state or self.fresh_state
            if self.passivity is not None:
                taps.passivity(now_ns, self.passivity.energy_J, self.passivity.damping)
            # (the robot holds when the force is off on its side at once, or at the master: the tick after a silent
            # master too, whose command was made before its state came back)
            self._servo(now_ns, self._delayed_state(now_ns, state), command.enabled and not reason, taps)
        self.haptic_on_ticks += command.enabled
        if reason_kind(command.reason) != reason_kind(self.haptic_reason):
            self.on_event(
                Event(now_ns, "haptic_enabled", "haptic force on")
                if command.enabled
                else Event(now_ns, "haptic_disabled", f"haptic force zeroed: {command.reason}")
            )
            self.haptic_reason = command.reason
        self.status.haptic_enabled, self.status.reason = command.enabled, command.reason
        self.status.latched = self.gate.latched

    def _silent_master(self, now_ns: int) -> str:
        """Why the master's own state says no hand is on it now ("" when it is fresh and sane): a master silent for
        ``teleop.WATCHDOG_NS`` gets zero force, as the robot holds (the first tick, before any state, too)."""
        assert self.teleop is not None  # (teleoperation is on)
        return self.teleop.absent(now_ns, self.fresh_state)

    def _at_the_master(self, now_ns: int, inputs: tuple, silent: str) -> HapticCommand:
        """The master's command at ``now_ns``: from the governor's inputs (the estimate and the gate's reason) sent
        ``delay_s`` ago (none yet: zero), the passivity controller's damping added before the governor's clamp,
        rate limit and output check; zero while the master itself is ``silent`` (its reason, no delay: it is
        the master's own)."""
        if self.delay_ns:
            self.in_flight.append((now_ns, inputs))
            while self.in_flight and self.in_flight[0][0] <= now_ns - self.delay_ns:
                self.arrived = self.in_flight.popleft()[1]
            inputs = self.arrived or (None, None, None, "link delay: nothing has arrived from the robot's side yet")
        force_S, R_BS, source_t_ns, reason = inputs
        reason = reason or silent
        assert self.passivity is not None  # (teleoperation is on)
        dt = 0.0 if self.last_sent_ns is None else (now_ns - self.last_sent_ns) * 1e-9
        self.last_sent_ns = now_ns
        self.passivity.observe(None if self.last_state is None else self.last_state.v_DHo_D, dt)
        command = self.governor.command(
            now_ns, force_S, R_BS, reason=reason, source_t_ns=source_t_ns, port=self.passivity.damp
        )
        self.passivity.hold(command.force_D)
        return command

    def _delayed_state(self, now_ns: int, state: DeviceState | None) -> DeviceState | None:
        """The master's state as teleoperation receives it ``delay_s`` later (stamped with its own time plus the
        delay: the link's delay is not a stale device, a device that repeats an old state is); None until the
        first has arrived."""
        if not self.delay_ns:
            return state
        if state is not None:
            self.states_in_flight.append(state)
        arrived = None
        while self.states_in_flight and self.states_in_flight[0].t_ns <= now_ns - self.delay_ns:
            arrived = self.states_in_flight.popleft()
        if arrived is None:
            return None
        t_ns = arrived.t_ns + self.delay_ns  # (when it arrived: a master that repeats an old state still goes stale)
        return DeviceState(t_ns, arrived.quat_DH, arrived.p_DoHo_D, arrived.buttons, arrived.v_DHo_D)

    def zero(self, end_ns: int, reason: str, taps: Taps) -> HapticCommand:
        """The session's final zero command: sent (an ``error`` event if it cannot be) and recorded; a tare still
        waiting refused."""
        zero = self.governor.command(end_ns, None, None, reason=reason)
        for event in self.tare.unanswered(end_ns):
            self.on_event(event)
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
            if event.kind == "teleop_following" and self.passivity is not None:  # (re-)engaged
                self.passivity.reset()
        if target is not None:
            self.call("kinematics", self.s.robot.servo_cp, target.t_ns, target.R_BE, target.p_BoEo_B)
            taps.robot_target(target)
            self.status.teleop = target.mode if not target.reason else f"{target.mode}: {target.reason}"

    def watch_button(self, state) -> None:
        """A press of the re-arm (tare) button (up, then down: a held button counts once) asks for a re-arm (tare)."""
        for bit, requests in ((self.rearm_bit, self.rearm_requests), (self.tare_bit, self.tare.requests)):
            if bit < 0:
                continue
            down = True if state is None else bool((int(state.buttons) >> bit) & 1)  # no state: unknown
            if down and not self.button_down[bit] and state is not None:
                requests.append(f"button {bit}")
            self.button_down[bit] = down

    def _shadows_tared(self) -> None:
        """The shadow estimators told of a tare (each that can re-identifies its bias: they see the zeroed
        readings too)."""
        for shadow in self.s.shadows:
            if isinstance(shadow.estimator, Reidentifies):
                shadow.estimator.reidentify_bias("tare")
