"""The run loop: sensor and kinematics → aligner → estimators → haptic gate → device, all recorded.

Each iteration (one loop period, paced by ``pacing``):

1. read new poses and wrench samples up to now, record them;
2. pair each wrench with its orientation (``core.aligner``), record that;
3. feed the usable samples (not stale, status good, finite) to the primary
   estimator, record its estimates and events;
4. turn the primary estimate into one force command (``gate`` says whether,
   ``safety.ForceGovernor`` how much), send and record it; with ``[teleop]``
   on, turn the master's state into the robot's next target (``command``);
5. feed the same samples to the shadow estimators (recorded, never rendered:
   after the command, so their time is not on a sample's path to its command).

Whatever ends the session, it ends the same way (``ending``): the final zero
command sent and recorded, the devices closed, the file finished; a sensor,
robot or estimator that raised is then a :class:`SessionError`.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hapticlab.core.aligner import Aligner
from hapticlab.core.errors import ConfigError
from hapticlab.core.host.interfaces import HasCalibration, HasLatency, HasRange, PreparesAhead, ReadsBlocks
from hapticlab.core.types import Event, WrenchBlock
from hapticlab.sessions.live.build import (
    EstimatorSlot,
    Session,
    check_live_address,
    default_out_path,
    refuse_existing_outputs,
    session_metadata,
)
from hapticlab.sessions.live.command import HapticCommander
from hapticlab.sessions.live.ending import (
    PartFailedError,
    close_devices,
    ending_message,
    final_params,
    save_for_next,
    signals_end_the_session,
    signals_noted,
)
from hapticlab.sessions.live.pacing import Pacer, freeze_the_heap
from hapticlab.sessions.live.priority import fifo_priority
from hapticlab.sessions.live.screen import screen
from hapticlab.sessions.live.status import SessionError, SessionResult, SessionStatus
from hapticlab.sessions.live.taps import HAND_OVER_NS, Taps
from hapticlab.sessions.recording import Recorder
from hapticlab.sessions.recording.process_sink import WriterProcessError
from hapticlab.sessions.settings import check_duration
from hapticlab.sessions.tools.library import check_name

PARAMS_INTERVAL_NS = 100_000_000
"""Parameters and covariance are recorded at 10 Hz (they change slowly; P⁻¹ costs µs)."""


def run_session(
    session: Session,
    out: str | Path | None = None,
    duration: float | None = None,
    on_status: Callable[[SessionStatus], None] | None = None,
    status_interval_s: float = 0.25,
    live: str = "",
    allow_network: bool = False,
) -> SessionResult:
    """Run a built session until its duration ends (or Ctrl-C) and record it to one MCAP file.

    ``live`` ("HOST:PORT", e.g. "127.0.0.1:8765") also serves the session while it runs over
    Foxglove's WebSocket protocol, the recording's topics as they are written (``foxglove-sdk``;
    the recording's writer process serves it, so the loop does not pay for it); on a loopback address
    only, unless ``allow_network`` (the view has no authentication).
    """
    if live:
        check_live_address(live, session.settings.recording_writer, allow_network)
    return LiveLoop(session, out, duration, on_status, status_interval_s, live).run()


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
        self.live = live
        settings = session.settings
        self.duration = settings.duration if duration is None else check_duration("duration", duration)
        self.path = Path(out) if out else default_out_path(settings)
        refuse_existing_outputs(self.path, saves_state=session.primary.saves is not None)
        self.period_ns = round(1e9 / settings.loop_rate_hz)
        self.duration_ns = round(self.duration * 1e9)
        self.gate = session.gate()
        self.sensor_range = session.sensor if isinstance(session.sensor, HasRange) else None
        sensor = session.sensor
        self.read_wrenches: Callable[[int], WrenchBlock] = (
            sensor.read_block
            if isinstance(sensor, ReadsBlocks)
            else lambda until_ns: WrenchBlock.from_samples(sensor.read(until_ns))
        )
        """The sensor's new readings as one block (its own ``read_block``, or its records made one)."""
        preparing = [
            (part, device)
            for part, device in (("sensor", session.sensor), ("kinematics", session.kinematics))
            if isinstance(device, PreparesAhead)
        ]
        self.aligner = Aligner(
            float(session.kinematics.rate_hz),
            latency_s=session.kinematics.latency_s if isinstance(session.kinematics, HasLatency) else 0.0,
        )
        self.on_status, self.status_interval_s = on_status, status_interval_s
        self.status = SessionStatus(rearm=self.rearm, tare=self.tare)
        self.commander = HapticCommander(session, self.gate, self.status, self._event, self._call)
        self.pacer = Pacer(
            self.period_ns, settings.realtime, settings.loop_rate_hz, preparing, self._call, self._event, self.status
        )
        self.next_status = 0.0
        self.events: list[Event] = []
        self.shadows = list(session.shadows)
        self.samples = self.poses = self.contact_samples = 0
        self.next_params_ns = 0
        self.recorder: Recorder | None = None
        self.priority = settings.realtime_priority if settings.realtime else 0
        """The loop thread's SCHED_FIFO priority while it ticks (0: the ordinary policy; set to 0 if refused)."""
        self.stopped_by = "Ctrl-C"  # or the signal that ended the session
        self.signals_while_ending: list[str] = []

    def rearm(self, source: str = "api") -> None:
        """Ask to re-arm a latched stop (any thread); honoured at the next tick, granted only once its cause is gone."""
        self.commander.rearm_requests.append(source)

    def tare(self, source: str = "api") -> None:
        """Ask (any thread) for a tare: the still, free tool's reading the zero (``tare.py``), at the next tick."""
        self.commander.tare.requests.append(source)

    def change_tool(self, name: str = "", source: str = "api") -> None:
        """Tell the session (any thread) its tool changed to ``name`` ("" unnamed): the force held until identified."""
        self.commander.request_tool_change(name and check_name(name, "tool name"), source)

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
            freeze_the_heap()
        self.t0_ns = now_ns = time.monotonic_ns()
        self.pacer.start(self.t0_ns)
        interrupted, failure = False, None
        with signals_end_the_session(lambda name: setattr(self, "stopped_by", name)):
            try:
                self._open()
                with fifo_priority(self.priority) as refused:  # paced: woken on time (priority.py)
                    if refused:
                        self.priority = 0
                        why = f"the loop runs at the ordinary priority: {refused}"
                        self._event(Event(time.monotonic_ns(), "realtime_priority_unavailable", why))
                    tick = 0
                    while (tick + 1) * self.period_ns <= self.duration_ns:  # every tick due within the session
                        # (paced: the one due at its end too, read just after)
                        tick, now_ns = self.pacer.next_tick(tick)
                        if tick * self.period_ns > self.duration_ns:  # fell behind past the end
                            break
                        self._tick(now_ns)
                # paced, the session ends now, its last tick done (a moment after the end was due); simulated,
                # at its duration
                now_ns = time.monotonic_ns() if self.s.settings.realtime else self.t0_ns + self.duration_ns
            except KeyboardInterrupt:
                interrupted = True
            except PartFailedError as exc:
                failure = exc
            with signals_noted(self.signals_while_ending):
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

    def _tick(self, now_ns: int) -> None:
        """One loop period: read, align, estimate, command; every stage recorded."""
        poses = self._call("kinematics", self.s.kinematics.read, now_ns)
        if poses:
            self.aligner.add_poses(poses)
            self.gate.on_poses(poses, now_ns)
            self.taps.poses(poses, now_ns)
            self.poses += len(poses)
            self.commander.last_pose = poses[-1]
        wrenches = self._call("sensor", self.read_wrenches, now_ns)
        estimated = None  # (the block the primary estimated, with its parameters recorded or not)
        if len(wrenches):
            self.taps.wrenches(wrenches)
            self.samples += len(wrenches)
            block = self.aligner.align(wrenches)
            self.taps.aligned(block)
            usable, _, reason = screen(block, self.sensor_range)  # (the sensor's own readings: its range)
            block = self.commander.tare.apply(block)  # (less the zero asked for: recorded as read, above)
            usable, reason = self.gate.on_samples(block, usable, reason, now_ns)
            some = True if not reason else usable.any()  # no reason: every sample is usable (the usual case)
            if not self.gate.trusts_poses(now_ns):  # their orientation is not the robot's: not for the estimators
                if some:
                    self.gate.on_withheld(block if not reason else block.subset(usable), *self._primary_model())
                some = False
            if some:
                block = block if not reason else block.subset(usable)
                estimated = (block, self._estimate(block, now_ns))
        for label, device in self.s.device_events:
            self._events(device.drain_events(), label)
        self.commander.command(now_ns, self.taps)
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
        if self.commander.tare.collecting:  # (a tare asked for: its window)
            self.commander.tare.watch(block, est)
        for event in self._drain(primary):
            self.gate.on_event(event, now_ns)
        params, R_SE = self._primary_model()
        self._gate_events(self.gate.on_estimates(block, est, now_ns, params, R_SE))
        R_BE = block.R_EB[-1].T
        R_BS = R_BE if R_SE is None else R_BE @ R_SE.T
        self.commander.last_estimate = (est.contact_force_S[-1], R_BS, int(est.t_ns[-1]))
        self.status.contact = bool(est.contact[-1])
        self.contact_samples += int(np.count_nonzero(est.contact))
        return with_params

    def _gate_events(self, events: list[Event]) -> None:
        for event in events:
            if event.kind == "haptic_latched":  # a press from before the stop must not re-arm it
                self.commander.rearm_requests.clear()
            self._event(event)

    def _update_shadows(self, block, with_params: bool, now_ns: int) -> None:
        """The shadows on the block the primary estimated, after the command has gone out (they are
        recorded, never rendered: their time is not on the path from a sample to its command)."""
        for shadow in list(self.shadows):  # one that fails is dropped
            try:
                shadow_est = shadow.estimator.update_block(block)
            except Exception as exc:
                self.shadows.remove(shadow)
                why = f"shadow estimator {shadow.label} raised {type(exc).__name__}: {exc}; dropped"
                self._event(Event(now_ns, "error", why, {"source": shadow.label}))
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

    # ------------------------------------------------------------------ bookkeeping

    def _call(self, part: str, method, *args):
        """Call a device's or the primary estimator's method; what it raises ends the session, named."""
        try:
            return method(*args)
        except (KeyboardInterrupt, PartFailedError):
            raise
        except Exception as exc:
            plugin = self.s.plugins.get(part)  # "recording" is no plugin
            raise PartFailedError(f"{part} {plugin['name']}" if plugin else part, exc) from exc

    def _event(self, event: Event) -> None:
        self.taps.event(event)
        self.events.append(event)
        self.status.events += 1

    def _events(self, events: list[Event], source: str) -> list[Event]:
        for event in events:
            self._event(Event(event.t_ns, event.kind, event.message, {**event.data, "source": source}))
        return events

    def _report(self, now_ns: int) -> None:
        if self.on_status is None or time.monotonic() < self.next_status:
            return
        self.next_status = time.monotonic() + self.status_interval_s
        elapsed = (now_ns - self.t0_ns) * 1e-9
        s = self.status
        s.elapsed_s, s.samples = elapsed, self.samples
        s.rate_hz = self.samples / elapsed if elapsed > 0 else 0.0
        s.converged_force, s.converged_torque = self.gate.ready
        self._call("status callback", self.on_status, s)  # (raising in the tick: the session still ends cleanly)

    def _open(self) -> None:
        self._call("sensor", self.s.sensor.open, self.t0_ns)
        if isinstance(self.s.sensor, HasCalibration):  # a real sensor knows its calibration once it is open
            assert self.recorder is not None  # run() made it before opening the devices
            self.recorder.add_metadata("hapticlab.calibration", dict(self.s.sensor.calibration))
        self._call("kinematics", self.s.kinematics.open, self.t0_ns)
        self._call("haptic", self.s.haptic.open)
        started = f"session {self.s.settings.name!r} started, estimator {self.s.estimator_name}"
        self._event(Event(self.t0_ns, "session_start", started))
        if self.s.tool.name:
            self._event(Event(self.t0_ns, "tool", self.s.tool.message()))

    def _finish(self, end_ns: int, interrupted: bool, failure: PartFailedError | None) -> SessionResult:
        """Zero the device and record it, close the devices, save the state, finish the file."""
        self.pacer.overrun_event(end_ns)  # what the last second's overruns added up to
        reason = f"session ended by an error: {failure}" if failure else "session ended"
        self.commander.zero(end_ns, reason, self.taps)
        close_devices(self.s, end_ns, self._event, self._events)
        if failure is not None:
            self._event(Event(end_ns, "error", str(failure), {"part": failure.part}))
        primary = self.s.primary
        params = self.commander.tare.own(final_params(primary, self.samples, end_ns, self._event))  # (tare.py)
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
            "haptic_on_s": self.commander.haptic_on_ticks * self.period_ns * 1e-9,
            "overruns": self.pacer.overruns,
            "realtime_priority": self.priority,
            "signals_while_ending": self.signals_while_ending,
        }
        assert self.recorder is not None  # run() made it before the session started
        held = self.gate.reason(end_ns)  # (a tool is saved only when nothing held the force at the end)
        ending = (self.s, self.recorder, self.path, params, held, end_ns, self._event)
        saved = None if failure else save_for_next(*ending, self.commander.changed_from, self.commander.tare.active)
        if saved:
            summary["estimator_state_path"] = saved
        self._event(Event(end_ns, "session_end", ending_message(interrupted, self.stopped_by, failure is not None)))
        try:
            self.taps.send()
            self.recorder.close(summary=summary)
        except WriterProcessError:
            if failure is None or failure.part != "recording":
                raise
        return SessionResult.from_summary(self.path, summary, (end_ns - self.t0_ns) * 1e-9, self.events)
