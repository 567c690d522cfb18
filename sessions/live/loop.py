"""The run loop: sensor and kinematics → aligner → estimators → haptic gate → device, all recorded.

Each iteration (one loop period):

1. read new poses and wrench samples up to now, record them;
2. pair each wrench with its orientation (``core.aligner``), record that;
3. feed the usable samples (not stale, status good, finite) to the primary
   estimator, record its estimates and events;
4. turn the primary estimate into one force command (``gate`` says whether,
   ``safety.ForceGovernor`` how much), send and record it;
5. with ``[teleop]`` on, turn the master's state into the robot's next target
   (``teleop.Teleoperation``), send it (``servo_cp``) and record it;
6. feed the same samples to the shadow estimators (recorded, never rendered:
   after the command, so their time is not on a sample's path to its command).

A latched stop (``gate``) holds the force off until an explicit re-arm: a
press of the device's ``haptic.rearm_button`` (an edge: released, then pressed),
the ``r`` key of ``hapticlab run``, or :meth:`LiveLoop.rearm` (also handed to
status callbacks as ``SessionStatus.rearm``); each is honoured at the next tick.

Time: with ``realtime = true`` "now" is the monotonic wall clock, ticks are
due every period from the start (a tick that ends early first lets the devices
that can, ``PreparesAhead``, do the next ticks' work, then sleeps), and a loop that falls more than one period
behind skips the ticks it missed and records an ``overrun`` event saying how
far behind it was (at most one such event a second). With ``realtime = false``
(simulated devices as fast as the machine allows) "now" is the tick's own time.

The session always ends the same way, whatever ended it (its duration,
Ctrl-C, SIGTERM or SIGHUP, a sensor, robot or estimator that raised): the final zero command is
sent *and recorded*, the devices are closed, the estimator's state is saved,
an ``error`` event names what failed, the summary says ``interrupted`` and
``error``, and the MCAP file is finished. A failure then raises
:class:`SessionError` (its ``result.path`` is the complete recording). A
haptic device that raises is a lost device: the force is zeroed and the
session goes on recording; a shadow estimator that raises is dropped with an
event. While the session ends, further Ctrl-C, SIGTERM and SIGHUP are noted
and ignored, so the file is always finished.
"""

from __future__ import annotations

import gc
import json
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hapticlab.core.aligner import Aligner
from hapticlab.core.errors import OutputExistsError
from hapticlab.core.host.interfaces import (
    HasCalibration,
    HasForceLimit,
    HasLatency,
    HasRange,
    PreparesAhead,
    ReadsBlocks,
)
from hapticlab.core.host.registry import ConfigError
from hapticlab.core.types import Event, WrenchBlock
from hapticlab.sessions.live.build import EstimatorSlot, Session, calibration_path, default_out_path, session_metadata
from hapticlab.sessions.live.gate import HapticGate, screen
from hapticlab.sessions.live.priority import fifo_priority
from hapticlab.sessions.live.status import SessionError, SessionResult, SessionStatus
from hapticlab.sessions.live.taps import HAND_OVER_NS, Taps
from hapticlab.sessions.live.teleop import Teleoperation
from hapticlab.sessions.recording import Recorder
from hapticlab.sessions.recording.sinks import WriterProcessError
from hapticlab.sessions.settings import check_duration

PARAMS_INTERVAL_NS = 100_000_000
"""Parameters and covariance are recorded at 10 Hz (they change slowly; P⁻¹ costs µs)."""
PREPARE_AHEAD_TICKS = 10
"""A paced loop asks the devices that prepare ahead (``PreparesAhead``) for the next 10 ticks' samples, each
only while at least half a period is left before the next tick: a chunk that takes a simulated 7 kHz sensor
~1 ms then waits for an idle moment (a slow tick leaves too little, and so does the other device's chunk),
and there are ten of them before its samples are read. Asked for the next tick alone, both devices, it ran
after a slow tick too and made the next one late by more than a period: most of the overruns of a paced
7 kHz session (60 s, interleaved: 16, 15, 2 overruns before; 6, 6, 2 after)."""
OVERRUN_EVENT_INTERVAL_NS = 1_000_000_000
"""At most one ``overrun`` event a second; the ticks skipped in between are counted in it."""


def stale_timeout_ns(
    stale_timeout: float, sensor_rate_hz: float, loop_rate_hz: float, sensor_latency_s: float = 0.0
) -> int:
    """The age of the newest sensor sample at which the force is zeroed, ns: ``session.stale_timeout`` s, or
    when 0 (automatic) 1.5 sensor periods plus the sensor's latency plus one loop period."""
    period_ns = int(round(1e9 / loop_rate_hz))
    if stale_timeout > 0:
        return int(round(stale_timeout * 1e9))
    return int(round((1.5 / sensor_rate_hz + sensor_latency_s) * 1e9)) + period_ns


def check_live_address(address: str) -> None:
    """A ``--live`` address: ``HOST:PORT`` with a port in 0..65535 (ConfigError naming it otherwise)."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ConfigError(f"--live {address!r}: expected HOST:PORT, e.g. 127.0.0.1:8765")


def _freeze_the_heap() -> None:
    """Collect once, then keep everything built so far out of the collector's full passes (``gc.freeze``).

    A paced session's heap is mostly what was built before its first tick (numpy, scipy, numba, the
    plugins); a full (generation 2) collection went through all of it, 60-80 ms in one tick of a 7 kHz
    session, where the loop skips as many ticks. Frozen, a full pass sees only what the session made
    since: 8-22 ms. The collection here costs ~0.1 s before the clock starts; the session's end unfreezes.
    """
    gc.collect()
    gc.freeze()


class _PartFailed(Exception):
    """A device or estimator raised inside the loop; ``part`` names it."""

    def __init__(self, part: str, exc: BaseException):
        super().__init__(f"{part} raised {type(exc).__name__}: {exc}")
        self.part = part


def run_session(
    session: Session,
    out: str | Path | None = None,
    duration: float | None = None,
    on_status: Callable[[SessionStatus], None] | None = None,
    status_interval_s: float = 0.25,
    live: str = "",
) -> SessionResult:
    """Run a built session until its duration ends (or Ctrl-C) and record it to one MCAP file.

    ``live`` ("HOST:PORT", e.g. "127.0.0.1:8765") also serves the session while it runs over
    Foxglove's WebSocket protocol, the recording's topics as they are written (``foxglove-sdk``;
    the recording's writer process serves it, so the loop does not pay for it).
    """
    return LiveLoop(session, out, duration, on_status, status_interval_s, live).run()


STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextmanager
def _signals_end_the_session(loop: "LiveLoop"):
    """SIGTERM and SIGHUP end the session as Ctrl-C does (only the main thread can install handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        loop.stopped_by = signal.Signals(signum).name
        raise KeyboardInterrupt

    previous = {s: signal.signal(s, stop) for s in STOP_SIGNALS if s != signal.SIGINT}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


@contextmanager
def _signals_ignored(loop: "LiveLoop"):
    """While the session ends, a second Ctrl-C (or SIGTERM, SIGHUP) is noted, not obeyed: the file is finished."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {
        s: signal.signal(s, lambda signum, frame: loop.signals_while_ending.append(signal.Signals(signum).name))
        for s in STOP_SIGNALS
    }
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


class LiveLoop:
    """One session's loop and its bookkeeping (built by :func:`run_session`)."""

    def __init__(
        self,
        session: Session,
        out: str | Path | None,
        duration: float | None,
        on_status: Callable[[SessionStatus], None] | None,
        status_interval_s: float,
        live: str = "",
    ):
        self.s = session
        if live:
            check_live_address(live)
            if session.settings.recording_writer != "process":
                raise ConfigError(
                    "--live: the live view is served by the recording's writer process; "
                    'drop session.recording_writer = "inline"'
                )
        self.live = live
        settings = session.settings
        self.duration = settings.duration if duration is None else check_duration("duration", duration)
        self.path = Path(out) if out else default_out_path(settings)
        if self.path.exists():
            raise OutputExistsError(
                f"{self.path} already exists; choose another --out (recordings are never overwritten)"
            )
        self.period_ns = int(round(1e9 / settings.loop_rate_hz))
        self.duration_ns = int(round(self.duration * 1e9))
        sensor_latency_s = session.sensor.latency_s if isinstance(session.sensor, HasLatency) else 0.0
        stale_ns = stale_timeout_ns(
            settings.stale_timeout, float(session.sensor.rate_hz), settings.loop_rate_hz, sensor_latency_s
        )
        self.gate = HapticGate(
            session.estimator_name,
            session.haptic_settings.ready_force_std,
            session.primary.parameter_std,
            session.primary.reidentifies,
            stale_ns,
            int(round(settings.frozen_pose_timeout * 1e9)),
            settings.max_turn_rate,
            settings.max_speed,
            reports_params=session.primary.reports_params is not None,
        )
        self.sensor_range = session.sensor if isinstance(session.sensor, HasRange) else None
        sensor = session.sensor
        self.read_wrenches: Callable[[int], WrenchBlock] = (
            sensor.read_block
            if isinstance(sensor, ReadsBlocks)
            else lambda until_ns: WrenchBlock.from_samples(sensor.read(until_ns))
        )
        """The sensor's new readings as one block (its own ``read_block``, or its records made one)."""
        self.preparing = [
            (part, device)
            for part, device in (("sensor", session.sensor), ("kinematics", session.kinematics))
            if isinstance(device, PreparesAhead)
        ]
        self.governor = session.governor()
        self.force_limit = session.haptic if isinstance(session.haptic, HasForceLimit) else None
        self.rearm_bit = session.haptic_settings.rearm_button  # -1: no button
        self.button_down = True  # unknown counts as held: a button held at the start must be released first
        self.rearm_requests: deque[str] = deque()
        self.teleop = Teleoperation(session.teleop_settings, self.governor.R_DB) if session.robot is not None else None
        self.last_pose = None  # the newest measured flange pose (what teleoperation starts from)
        self.aligner = Aligner(
            float(session.kinematics.rate_hz),
            latency_s=session.kinematics.latency_s if isinstance(session.kinematics, HasLatency) else 0.0,
        )
        self.on_status, self.status_interval_s = on_status, status_interval_s
        self.status = SessionStatus(rearm=self.rearm)
        self.next_status = 0.0
        self.events: list[Event] = []
        self.shadows = list(session.shadows)
        self.samples = self.poses = self.contact_samples = self.haptic_on_ticks = 0
        self.overruns = self.skipped_since_event = 0
        self.behind_max_ns = 0
        self.next_overrun_event_ns = 0
        self.next_params_ns = 0
        self.last_estimate: tuple[np.ndarray, np.ndarray, int] | None = None  # (contact_force_S, R_BS, t_ns)
        self.haptic_reason = "starting"
        self.recorder: Recorder | None = None
        self.priority = settings.realtime_priority if settings.realtime else 0
        """The loop thread's SCHED_FIFO priority while it ticks (0: the ordinary policy; set to 0 if refused)."""
        self.stopped_by = "Ctrl-C"  # or the signal that ended the session
        self.signals_while_ending: list[str] = []

    def rearm(self, source: str = "api") -> None:
        """Ask to re-arm a latched stop (any thread); honoured at the next tick, granted only once its cause is gone."""
        self.rearm_requests.append(source)

    # ------------------------------------------------------------------ the loop

    def run(self) -> SessionResult:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            # the taps hold up to HAND_OVER_NS before the recorder sees it: flushed that much sooner, a killed
            # session still loses at most its last second
            self.recorder = Recorder(
                self.path,
                metadata=session_metadata(self.s, self.duration, self.path),
                flush_interval_s=1.0 - HAND_OVER_NS * 1e-9,
                writer=self.s.settings.recording_writer,
                live=self.live,
            )
        except WriterProcessError as exc:
            if self.live and "live view" in str(exc):  # the address taken, or no foxglove-sdk: the user's to fix
                why = str(exc).rpartition(": live view on ")[2].partition(": ")[2]
                raise ConfigError(f"--live {self.live}: the live view did not start: {why}") from None
            raise
        self.status.live_address = self.recorder.live_address
        self.taps = Taps(self.recorder)
        if self.s.settings.realtime:
            _freeze_the_heap()
        self.t0_ns = now_ns = time.monotonic_ns()
        interrupted, failure = False, None
        with _signals_end_the_session(self):
            try:
                self._open()
                with fifo_priority(self.priority) as refused:  # paced: woken on time (priority.py)
                    if refused:
                        self.priority = 0
                        self._event(
                            Event(
                                time.monotonic_ns(),
                                "realtime_priority_unavailable",
                                f"the loop runs at the ordinary priority: {refused}",
                            )
                        )
                    tick = 0
                    while (tick + 1) * self.period_ns <= self.duration_ns:  # every tick due within the session
                        tick, now_ns = self._next_tick(tick)  # (paced: the one due at its end too, read just after)
                        if tick * self.period_ns > self.duration_ns:  # fell behind past the end
                            break
                        self._tick(now_ns)
                # paced, the session ends now, its last tick done (a moment after the end was due); simulated,
                # at its duration
                now_ns = time.monotonic_ns() if self.s.settings.realtime else self.t0_ns + self.duration_ns
            except KeyboardInterrupt:
                interrupted = True
            except _PartFailed as exc:
                failure = exc
            with _signals_ignored(self):
                try:
                    result = self._finish(now_ns, interrupted, failure)
                finally:
                    if self.s.settings.realtime:
                        gc.unfreeze()  # the caller's heap as it was (a script may run many sessions)
        if failure is not None:
            kept = (
                f"salvage what it wrote with: hapticlab recover {self.path}"
                if failure.part == "recording"
                else f"the recording is complete: {self.path}"
            )
            raise SessionError(f"{failure}; {kept}", failure.part, result) from failure.__cause__
        return result

    def _next_tick(self, tick: int) -> tuple[int, int]:
        """The next tick's number and time: the tick's own time, or (realtime) the wall clock at its deadline."""
        tick += 1
        due_ns = self.t0_ns + tick * self.period_ns
        if not self.s.settings.realtime:
            return tick, due_ns
        now_ns = time.monotonic_ns()
        for part, device in self.preparing:  # time to spare: the devices' work, now (each while it lasts)
            if due_ns - now_ns < self.period_ns // 2:
                break
            self._call(part, device.prepare, due_ns + PREPARE_AHEAD_TICKS * self.period_ns)
            now_ns = time.monotonic_ns()
        if now_ns < due_ns:
            self.status.behind_s = 0.0
            time.sleep((due_ns - now_ns) * 1e-9)
            return tick, time.monotonic_ns()
        behind_ns = now_ns - due_ns
        if behind_ns > self.period_ns:  # fell behind: skip the ticks missed, say so
            skipped = behind_ns // self.period_ns
            self._overrun(now_ns, behind_ns, int(skipped))
            tick += int(skipped)
        return tick, now_ns

    def _tick(self, now_ns: int) -> None:
        """One loop period: read, align, estimate, command; every stage recorded."""
        poses = self._call("kinematics", self.s.kinematics.read, now_ns)
        if poses:
            self.aligner.add_poses(poses)
            self.gate.on_poses(poses, now_ns)
            self.taps.poses(poses, now_ns)
            self.poses += len(poses)
            self.last_pose = poses[-1]
        wrenches = self._call("sensor", self.read_wrenches, now_ns)
        estimated = None  # (the block the primary estimated, with its parameters recorded or not)
        if len(wrenches):
            self.taps.wrenches(wrenches)
            self.samples += len(wrenches)
            block = self.aligner.align(wrenches)
            self.taps.aligned(block)
            usable, _, reason = screen(block, self.sensor_range)
            self.gate.on_samples(block, reason)
            some = True if not reason else usable.any()  # no reason: every sample is usable (the usual case)
            if not self.gate.trusts_poses(
                now_ns
            ):  # their orientation is not the robot's: keep them from the estimators
                if some:
                    self.gate.on_withheld(block if not reason else block.subset(usable), *self._primary_model())
                some = False
            if some:
                block = block if not reason else block.subset(usable)
                estimated = (block, self._estimate(block, now_ns))
        for label, device in self.s.device_events:
            self._events(device.drain_events(), label)
        self._command(now_ns)
        if estimated is not None and self.shadows:
            self._update_shadows(*estimated, now_ns)
        self._report(now_ns)
        self._call("recording", self.taps.send, now_ns)  # encoded now, the command gone; handed over every 20 ms

    # ------------------------------------------------------------------ the stages

    def _estimate(self, block, now_ns: int) -> bool:
        """The primary estimator on ``block``, its estimates recorded, the gate told; True when its
        parameters were recorded with them (every ``PARAMS_INTERVAL_NS``)."""
        with_params = now_ns >= self.next_params_ns
        if with_params:
            self.next_params_ns = now_ns + PARAMS_INTERVAL_NS
        primary = self.s.primary
        est = self._call("estimator", primary.estimator.update_block, block)
        self._record_estimates(primary, est, with_params)
        for event in self._drain(primary):
            self.gate.on_event(event, now_ns)
        params, R_SE = self._primary_model()
        for event in self.gate.on_estimates(block, est, now_ns, params, R_SE):
            if event.kind == "haptic_latched":  # a press from before the stop must not re-arm it
                self.rearm_requests.clear()
            self._event(event)
        R_BE = block.R_EB[-1].T
        R_BS = R_BE if R_SE is None else R_BE @ R_SE.T
        self.last_estimate = (est.contact_force_S[-1], R_BS, int(est.t_ns[-1]))
        self.status.contact = bool(est.contact[-1])
        self.contact_samples += int(np.count_nonzero(est.contact))
        return with_params

    def _update_shadows(self, block, with_params: bool, now_ns: int) -> None:
        """The shadows on the block the primary estimated, after the command has gone out (they are
        recorded, never rendered: their time is not on the path from a sample to its command)."""
        for shadow in list(self.shadows):  # one that fails is dropped
            try:
                shadow_est = shadow.estimator.update_block(block)
            except Exception as exc:
                self.shadows.remove(shadow)
                self._event(
                    Event(
                        now_ns,
                        "error",
                        f"shadow estimator {shadow.label} raised {type(exc).__name__}: {exc}; dropped",
                        {"source": shadow.label},
                    )
                )
                continue
            self._record_estimates(shadow, shadow_est, with_params)
            self._drain(shadow)

    def _primary_model(self) -> tuple[dict[str, list[float]] | None, np.ndarray | None]:
        """The primary estimator's parameters (once the gate knows them to be identified) and its mount R_SE."""
        primary = self.s.primary
        params = primary.params() if self.gate.parameters_known else None
        return params, None if primary.mount is None else primary.mount.R_SE

    def _record_estimates(self, slot: EstimatorSlot, est, with_params: bool) -> None:
        if with_params:
            self.taps.estimates(slot.topic, est, slot.params() or {}, slot.cov_diag() or [])
        else:
            self.taps.estimates(slot.topic, est)

    def _drain(self, slot: EstimatorSlot) -> list[Event]:
        return self._events(slot.events.drain_events(), slot.label) if slot.events is not None else []

    def _command(self, now_ns: int) -> None:
        reason = self.gate.reason(now_ns)
        while self.rearm_requests:
            event = self.gate.rearm(now_ns, self.rearm_requests.popleft())
            if event is not None:
                self._event(event)
                reason = self.gate.reason(now_ns)
        fault = self.gate.fault_event(reason, now_ns)
        if fault is not None:
            self._event(fault)
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
        self.taps.command(command)
        if state is not None:
            self.taps.device_state(state)
        self._watch_button(state)
        if self.teleop is not None:
            self._servo(now_ns, state, command.enabled)
        self.haptic_on_ticks += command.enabled
        if command.reason.split(" (")[0] != self.haptic_reason.split(" (")[0]:  # not each new figure in it
            self._event(
                Event(now_ns, "haptic_enabled", "haptic force on")
                if command.enabled
                else Event(now_ns, "haptic_disabled", f"haptic force zeroed: {command.reason}")
            )
            self.haptic_reason = command.reason
        self.status.haptic_enabled, self.status.reason = command.enabled, command.reason
        self.status.latched = self.gate.latched

    def _servo(self, now_ns: int, state, haptic_on: bool) -> None:
        """The robot's next target from the master's state: sent (``servo_cp``) and recorded."""
        target, events = self.teleop.step(now_ns, self.last_pose, state, haptic_on)
        for event in events:
            self._event(event)
        if target is not None:
            self._call("kinematics", self.s.robot.servo_cp, target.t_ns, target.R_BE, target.p_BoEo_B)
            self.taps.robot_target(target)
            self.status.teleop = target.mode if not target.reason else f"{target.mode}: {target.reason}"

    def _watch_button(self, state) -> None:
        """A press of the re-arm button (up, then down: a held button counts once) asks for a re-arm."""
        if self.rearm_bit < 0:
            return
        down = True if state is None else bool((int(state.buttons) >> self.rearm_bit) & 1)  # no state: unknown
        if down and not self.button_down and state is not None:
            self.rearm_requests.append(f"button {self.rearm_bit}")
        self.button_down = down

    # ------------------------------------------------------------------ bookkeeping

    def _call(self, part: str, method, *args):
        """Call a device's or the primary estimator's method; what it raises ends the session, named."""
        try:
            return method(*args)
        except (KeyboardInterrupt, _PartFailed):
            raise
        except Exception as exc:
            plugin = self.s.plugins.get(part)  # "recording" is no plugin
            raise _PartFailed(f"{part} {plugin['name']}" if plugin else part, exc) from exc

    def _event(self, event: Event) -> None:
        self.taps.event(event)
        self.events.append(event)
        self.status.events += 1

    def _events(self, events: list[Event], source: str) -> list[Event]:
        for event in events:
            self._event(Event(event.t_ns, event.kind, event.message, {**event.data, "source": source}))
        return events

    def _overrun(self, now_ns: int, behind_ns: int, skipped: int) -> None:
        self.overruns += 1
        self.skipped_since_event += skipped
        self.behind_max_ns = max(self.behind_max_ns, behind_ns)
        self.status.behind_s = behind_ns * 1e-9
        if now_ns >= self.next_overrun_event_ns:
            self._overrun_event(now_ns)

    def _overrun_event(self, now_ns: int) -> None:
        """The overruns since the last such event, as one event (how far behind at most, ticks skipped)."""
        if self.skipped_since_event:
            rate = self.s.settings.loop_rate_hz
            self._event(
                Event(
                    now_ns,
                    "overrun",
                    f"loop {self.behind_max_ns * 1e-6:.1f} ms behind its {rate:g} Hz rate; "
                    f"{self.skipped_since_event} tick(s) skipped",
                    {"behind_s": self.behind_max_ns * 1e-9, "ticks_skipped": self.skipped_since_event},
                )
            )
            self.next_overrun_event_ns = now_ns + OVERRUN_EVENT_INTERVAL_NS
            self.skipped_since_event, self.behind_max_ns = 0, 0

    def _report(self, now_ns: int) -> None:
        if self.on_status is None or time.monotonic() < self.next_status:
            return
        self.next_status = time.monotonic() + self.status_interval_s
        elapsed = (now_ns - self.t0_ns) * 1e-9
        s = self.status
        s.elapsed_s, s.samples = elapsed, self.samples
        s.rate_hz = self.samples / elapsed if elapsed > 0 else 0.0
        s.converged_force, s.converged_torque = self.gate.ready
        self.on_status(s)

    def _open(self) -> None:
        self._call("sensor", self.s.sensor.open, self.t0_ns)
        if isinstance(self.s.sensor, HasCalibration):  # a real sensor knows its calibration once it is open
            self.recorder.add_metadata("hapticlab.calibration", dict(self.s.sensor.calibration))
        self._call("kinematics", self.s.kinematics.open, self.t0_ns)
        self._call("haptic", self.s.haptic.open)
        self._event(
            Event(
                self.t0_ns,
                "session_start",
                f"session {self.s.settings.name!r} started, estimator {self.s.estimator_name}",
            )
        )

    def _finish(self, end_ns: int, interrupted: bool, failure: _PartFailed | None) -> SessionResult:
        """Zero the device and record it, close the devices, save the state, finish the file."""
        self._overrun_event(end_ns)  # what the last second's overruns added up to
        reason = f"session ended by an error: {failure}" if failure else "session ended"
        zero = self.governor.command(end_ns, None, None, reason=reason)
        try:
            self.s.haptic.send(zero)
        except Exception as exc:
            self._event(Event(end_ns, "error", f"the final zero command could not be sent: {exc}"))
        self.taps.command(zero)
        for label, device in (("haptic", self.s.haptic), ("sensor", self.s.sensor), ("kinematics", self.s.kinematics)):
            try:
                device.close()
            except Exception as exc:
                self._event(Event(end_ns, "error", f"{label} did not close: {type(exc).__name__}: {exc}"))
        for label, device in self.s.device_events:  # what they said while closing (final health counters)
            try:
                self._events(device.drain_events(), label)
            except Exception as exc:
                self._event(Event(end_ns, "error", f"{label} events lost: {type(exc).__name__}: {exc}"))
        if failure is not None:
            self._event(Event(end_ns, "error", str(failure), {"part": failure.part}))
        primary = self.s.primary
        try:
            params = (primary.params() or {}) if self.samples else {}
        except Exception as exc:  # the estimator that just failed may fail again
            params = {}
            self._event(Event(end_ns, "error", f"estimator parameters unavailable: {exc}"))
        summary = {
            "samples": self.samples,
            "poses": self.poses,
            "interrupted": interrupted,
            "error": str(failure) if failure else "",
            "params": params,
            "first_converged_force": primary.counts.first_converged_force if primary.counts else None,
            "first_converged_torque": primary.counts.first_converged_torque if primary.counts else None,
            "convergence_flag_flips": {"force": self.gate.flips[0], "torque": self.gate.flips[1]},
            "contact_samples": self.contact_samples,
            "held_out_samples": primary.holds_out.held_out_samples if primary.holds_out else None,
            "haptic_on_s": self.haptic_on_ticks * self.period_ns * 1e-9,
            "overruns": self.overruns,
            "realtime_priority": self.priority,
            "signals_while_ending": self.signals_while_ending,
        }
        if primary.saves is not None and failure is None:
            try:  # never let a failing save cost the recording
                state = primary.saves.state()
                self.recorder.add_metadata("hapticlab.estimator_state", state)
                state_path = calibration_path(self.path)
                state_path.write_text(json.dumps(state, indent=1))
                summary["estimator_state_path"] = str(state_path)
            except Exception as exc:
                self._event(Event(end_ns, "estimator_state_not_saved", f"estimator state not saved: {exc}"))
        ending = (
            f"interrupted ({self.stopped_by})"
            if interrupted
            else "ended by an error"
            if failure
            else "session finished"
        )
        self._event(Event(end_ns, "session_end", ending))
        try:
            self.taps.send()
            self.recorder.close(summary=summary)
        except WriterProcessError:
            if failure is None or failure.part != "recording":
                raise
        return SessionResult(
            path=self.path,
            samples=self.samples,
            poses=self.poses,
            duration_s=(end_ns - self.t0_ns) * 1e-9,
            interrupted=interrupted,
            params=params,
            events=self.events,
            first_converged_force=summary["first_converged_force"],
            first_converged_torque=summary["first_converged_torque"],
            contact_samples=self.contact_samples,
            haptic_on_s=summary["haptic_on_s"],
            error=summary["error"],
            overruns=self.overruns,
            held_out_samples=summary["held_out_samples"],
        )
