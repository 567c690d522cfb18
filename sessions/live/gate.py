"""The haptic gate: at every tick, may the contact force reach the trainee's hand, and if not, why not.

The force is held at zero, the reason recorded with each command, on any doubt (docs/safety.md lists the
rules with their reasons):

* the data: no sensor data within the stale timeout; a status bit, a non-finite reading, one beyond the
  sensor's range (``screen.py``); a reading that jumped faster than any contact, or stuck
  (``watch.StepWatch``, ``watch.StuckWatch``);
* the poses: frozen, jumped, or out of step with the wrench (``watch.PoseWatch``, ``watch.LagWatch``);
* the estimator: not converged, or no longer (its parameters' std above ``ready_force_std`` again, or,
  without a std, its flag down for ``CONVERGENCE_LOSS_NS``: Algorithm 1's flag flickers while the estimate
  still settles); no weight model to check the poses with; its payload change (``PAYLOAD_HOLD_NS``);
* the frame the residual lives in (``drift.DriftWatch``): a step faster than soft tissue pushes is held
  until the residual turns with the world (a contact), keeps its direction in the world along gravity (a
  weight step), keeps it in the sensor (a bias step), or the estimator sees free motion for
  ``doubt.DOUBT_FREE_NS``; so is the session's first residual pulling straight down, no mass stated
  (``pull.PullWatch``: a support gone, or a contact); a residual that keeps its direction in the sensor
  while the tool turns (a bias step or drift, in contact or not) is re-identified by the estimator (or
  latches the force off until a re-arm, :meth:`HapticGate.rearm`), and the force waits for the residual to
  settle (a full window under ``drift.MIN_OFFSET_N``: a bias still drifting, or moved in a contact, stays off);
* where the residual acts, by its torque (``lever.LeverWatch``): twisting about its own line, or across the tool
  at the sensor, no touch gives it: held (what it is, the drift watch tells);
* the second channel, where the robot measures its own wrench (``crosscheck.WrenchCrossCheck``): the
  contact force off the robot's by more than its stated accuracy; a sudden step both show is a contact.

Every fault (not the estimator's ordinary warming up) is also an event naming it, when it starts; a latched
stop is ``haptic_latched``, a re-arm ``haptic_rearmed``, a refused one ``haptic_rearm_refused`` naming why.
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.core.host.interfaces import WEIGHT_MODEL, Reidentifies, ReidentifiesWeight, ReportsParameterStd
from hapticlab.core.types import AlignedSamples, Estimates, Event, PoseSample
from hapticlab.sessions.live import gate_kernel as screen_kernel
from hapticlab.sessions.live.convergence import ConvergenceFlags
from hapticlab.sessions.live.crosscheck import WrenchCrossCheck
from hapticlab.sessions.live.doubt import SUDDEN, Doubt
from hapticlab.sessions.live.drift import MIN_OFFSET_N, WEIGHT_TILT, DriftWatch, along
from hapticlab.sessions.live.lever import LeverWatch
from hapticlab.sessions.live.pose_trust import PoseTrust
from hapticlab.sessions.live.pull import PULL, PullWatch, down_B, rearm_refusal
from hapticlab.sessions.live.stated_weight import StatedWeight
from hapticlab.sessions.live.watch import StepWatch, StuckWatch

PAYLOAD_HOLD_NS = 1_000_000_000
"""After an estimator's payload change the haptic force is held at zero this long (1 s): the change
may be a load held by the tool (a grasped object) rather than a new tool, and its release would then
show as a phantom force until the estimator sees the second change."""
CONVERGENCE_LOSS_NS = 20_000_000
"""A converged force stage whose flag has been down this long (20 ms of samples) is no longer converged."""
LATCHED = "sensor bias step: re-arm needed"
"""The reason of the latched stop after a bias step the estimator cannot re-identify."""
WARMING_UP = ("estimator not converged", "parameters not yet identified")
"""Reasons that are the estimator's ordinary start, not faults (no event of their own)."""


class HapticGate:
    """Tracks the data and the primary estimator, and tells the loop why the force must be zero.

    Args:
        label: the estimator's label, for event messages.
        ready_force_std: the force-stage parameters' std below which the force may go on, N.
        parameter_std: the estimator when it reports that std (else None: convergence alone decides).
        reidentifies: the estimator when it can re-identify its bias (else None: a bias step latches).
        reidentifies_weight: the same for the tool's weight (else None: a weight step latches).
        stale_timeout_ns: oldest newest-sample age before "no sensor data", ns.
        frozen_pose_timeout_ns: longest run of identical poses before "kinematics frozen", ns.
        max_turn_rate: fastest turn between two poses before "kinematics jumped", rad/s.
        max_speed: fastest motion between two poses before "kinematics jumped", m/s.
        wrench_accuracy_N: the robot's own wrench's stated accuracy, N (``MeasuresWrench``; 0: it has none).
        tool_mass: the tool's stated mass, kg (``[haptic] tool_mass``; 0: not stated).
        tool_axis_S: the tool's axis in S (``[haptic] tool_axis``), for the lever arm of the residual.
    """

    def __init__(
        self,
        label: str,
        ready_force_std: float,
        parameter_std: ReportsParameterStd | None,
        reidentifies: Reidentifies | None,
        stale_timeout_ns: int,
        frozen_pose_timeout_ns: int,
        max_turn_rate: float,
        max_speed: float,
        reports_params: bool = True,
        reidentifies_weight: ReidentifiesWeight | None = None,
        wrench_accuracy_N: float = 0.0,
        tool_mass: float = 0.0,
        tool_axis_S: tuple[float, float, float] = (0.0, 0.0, 1.0),
    ):
        self.label = label
        self.ready_force_std, self.parameter_std = ready_force_std, parameter_std
        self.reidentifies, self.reidentifies_weight = reidentifies, reidentifies_weight
        self.stale_timeout_ns = stale_timeout_ns
        self.trust = PoseTrust(frozen_pose_timeout_ns, max_turn_rate, max_speed, reports_params)
        self.poses, self.lag = self.trust.poses, self.trust.lag
        self.drift, self.lever = DriftWatch(), LeverWatch(tool_axis_S)
        self.steps, self.stuck = StepWatch(), StuckWatch()
        self.stated = StatedWeight(tool_mass) if tool_mass > 0 else None  # the identified weight checked against it
        self.pull = None if self.stated else PullWatch()  # (a stated weight tells a pull down from the weight)
        self.cross = WrenchCrossCheck(wrench_accuracy_N)  # the robot's own wrench (accuracy 0: none, it idles)
        screen_kernel.warm_up()  # compiled (or loaded) before the first tick
        self.flags = ConvergenceFlags(label)
        self.ready, self.converged, self.flips = self.flags.ready, self.flags.converged, self.flags.flips  # (its lists)
        self.parameters_known, self.parameters_lost, self.hold_until_ns = False, False, 0
        self.unidentified = ""  # the estimator's last not_identifiable message about the weight ("" none)
        self.bias_hold = ""  # "" | "drop", "rise" (waiting for the flag to) | "settle" (the residual) | "latched"
        self.hold_cause = "sensor bias step"  # what the hold is for: "sensor bias step" | "weight step" | "re-armed"
        self.contact_now, self.doubt = False, Doubt()  # the estimator's newest contact flag; the step in hand
        self.last_residual: tuple = (np.zeros(3), np.eye(3), None)  # newest block's mean residual (S), R_EB, R_SE
        self.pull_latched_B = np.zeros(3)  # (the pull straight down that latched, N in B)
        self.last_sample_ns: int | None = None
        self.data_reason = self.fault = ""  # (the fault: what the last event named)

    def trusts_poses(self, now_ns: int) -> bool:
        """The poses may be paired with the wrench (``pose_trust``; when not, :meth:`on_withheld` takes the samples)."""
        return self.trust.trusted(now_ns)

    def on_withheld(
        self, block: AlignedSamples, params: dict[str, list[float]] | None, R_SE: np.ndarray | None
    ) -> None:
        """Samples kept from the estimators because the poses are not trusted: the lag watch still sees them."""
        if self.parameters_known and params is not None and not self.trust.frozen():
            self.trust.watch_lag(block, params, R_SE)

    def on_poses(self, poses: list[PoseSample], now_ns: int) -> None:
        """New poses arrived at ``now_ns``: a jump starts the lag watch afresh."""
        self.trust.add_poses(poses, now_ns)
        self.cross.add_robot(poses)

    def on_samples(self, block: AlignedSamples, usable: np.ndarray, reason: str, now_ns: int) -> tuple[np.ndarray, str]:
        """A new sensor block arrived (every sample), with the screen's ``usable`` mask and ``reason``
        (``screen.screen``): those with the samples of a reading that jumped faster than any contact held out
        (``watch.StepWatch``); a jump that stayed, or a sudden step, holds the force until the drift watch tells
        a contact from the sensor."""
        self.last_sample_ns = int(block.t_ns[-1])
        held = self.steps.add(block.t_ns, block.force_S)
        stuck = self.stuck.add(block.t_ns, block.force_S, block.torque_S)
        step, self.steps.persisted = self.steps.persisted, None  # (held out until now: the new level goes on)
        jumped = "" if step is None else f"the reading jumped {np.linalg.norm(step):.3g} N and stayed"
        what = self.steps.sudden or jumped
        self.steps.sudden = ""
        if what and self.parameters_known and self.bias_hold in ("", "settle"):  # the motion decides what it was
            self._start_doubt(what)
        if held.any():
            self.cross.mark(self.last_sample_ns)  # (the step, if it stays, is measured from before it)
            usable, reason = usable & ~held, reason or self.steps.jump
        if stuck.any():
            stuck_for = f"sensor stuck (the same reading for {self.stuck.stuck_ns * 1e-6:.0f} ms)"
            usable, reason = usable & ~stuck, reason or stuck_for
        self.data_reason = reason
        return usable, reason

    def _start_doubt(self, what: str, kind: str = SUDDEN) -> None:
        """Hold the force over a step ``what`` until the motion tells (the drift watch afresh: only what follows)."""
        self.doubt.open(what, kind, self.contact_now)
        self.drift.reset()
        self.cross.mark(self.last_sample_ns or 0)

    def on_estimates(
        self,
        block: AlignedSamples,
        est: Estimates,
        now_ns: int,
        params: dict[str, list[float]] | None = None,
        R_SE: np.ndarray | None = None,
    ) -> list[Event]:
        """The primary estimator's output for the usable samples: the events it makes (convergence, bias step)."""
        events = []
        self.contact_now = bool(est.contact[-1])
        self.last_residual = (est.contact_force_S.mean(axis=0), block.R_EB[-1], R_SE)
        self.cross.add_contact(est.t_ns, est.contact_force_S, block.R_EB, R_SE)
        events += self.flags.add(est)
        if self.ready[0] and not self.parameters_known:
            std = self._std()
            self.parameters_known = std is None or std <= self.ready_force_std
            if self.parameters_known and std is not None:
                events.append(Event(now_ns, "parameters_known", f"force parameters known to ±{std:.3g} N (1σ)"))
        elif self.parameters_known and (std := self._std()) is not None:  # (None: no parameter_std)
            # (lost: e.g. a drifting estimator in a long contact, a NaN std; known again: held until it settles)
            lost, self.parameters_lost = self.parameters_lost, not std <= self.ready_force_std
            if lost and not self.parameters_lost and not self.bias_hold:  # (what it took in while lost shows then)
                self.bias_hold, self.hold_cause = "settle", "parameters known again"
                self.drift.reset()
        if self.bias_hold == "drop" and not self.converged[0]:
            self.bias_hold = "rise"
        # (and the parameters known again: kalman's flag at the pose is back before the tool is re-identified)
        elif self.bias_hold == "rise" and self.converged[0] and not self.parameters_lost:
            self.bias_hold = "settle"
            self.drift.reset()
            message = f"{self.label} converged again after the {self.hold_cause}"
            events.append(Event(now_ns, "bias_reidentified", message))
        if self.parameters_known and params is not None:
            self.trust.watch_lag(block, params, R_SE)
        g_B = None if params is None else params.get("gravity_force_B")
        if self.pull is not None and g_B is not None and self.parameters_known:  # (fed throughout: it tracks onsets)
            pull = self.pull.add(est.contact_force_S, block.R_EB, R_SE, g_B)
            if pull and not self.doubt and not self.bias_hold:
                self._start_doubt(pull, PULL)
        # (once the parameters are known, as the lag watch: before, a residual says nothing of the sensor's bias)
        judged = self.parameters_known and self.bias_hold in ("", "settle")
        verdict = self.drift.add(est.t_ns, est.contact_force_S, block.R_EB, R_SE) if judged else ""
        if self.bias_hold == "settle" and self.drift.size < MIN_OFFSET_N:
            self.bias_hold = ""
            events.append(Event(now_ns, "bias_settled", f"the residual settled under {MIN_OFFSET_N:g} N"))
        if verdict == "sensor":
            in_S, in_B = self.drift.misfits
            how = "the residual force kept its direction in the sensor frame while the tool turned "
            how += f"(off it by {in_S:.2f} N RMS in the sensor, {in_B:.2f} N in the world): the sensor's zero moved, "
            how += "or the estimator took a contact into its bias"
            events += self._reidentify(self.drift.offset_S, now_ns, how)
        elif verdict == "world" and self.doubt and not self.doubt.from_contact:
            # (from a contact, the window holds the contact with the step: only its end or the sensor tells)
            down = g_B is not None and along(self.drift.direction_B, down_B(g_B), WEIGHT_TILT)
            if down and self.doubt.kind == PULL:  # (a contact pulling down reads the same: a person says which)
                why = f"{self.doubt.what}; it kept its direction in the world: the support it rested on gone, or "
                why += "a contact; free the tool and re-arm to take it as its weight (or state haptic.tool_mass)"
                events += self._latch(PULL, now_ns, why)
                self.pull_latched_B = self.drift.size * self.drift.direction_B
            elif down:
                how = f"{self.doubt} kept its direction in the world, pulling down: the tool's weight changed "
                how += "(a load hung on it, or the support it started resting on gone), not a contact"
                events += self._reidentify(self.drift.size * self.drift.direction_B, now_ns, how, "weight_step")
            else:
                message = f"{self.doubt} turned with the world: a contact"
                events.append(Event(now_ns, "contact_confirmed", message))
                self.doubt.close()
        judge = self.parameters_known and self.parameter_std is not None and self.bias_hold in ("", "settle")
        # (batch, no parameter std: its residual torque errs as no touch does)
        self.lever.add(est.t_ns, est.contact_force_S, est.contact_torque_S, judge and bool(est.converged_torque[-1]))
        step = np.asarray(self.cross.step_B) / (math.hypot(*self.cross.step_B) or 1.0)
        if self.doubt and self.cross.confirmed and not (g_B is not None and along(step, g_B, WEIGHT_TILT)):
            # the robot's own wrench saw it too: a contact (a load hung on, or a tool changed, steps both alike)
            message = f"{self.doubt}: {self.cross.confirmed}"
            events.append(Event(now_ns, "contact_confirmed", message))
            self.doubt.close()
        if self.stated is not None and g_B is not None and not self.bias_hold:  # (a reason while off it)
            self.stated.check(g_B)  # (without ReidentifiesWeight the force stays held: a latch would not re-arm)
            residual_B = self.drift.means_B[-1] if self.drift.means_B else None
            if self.reidentifies_weight and (gone := self.stated.step(int(est.t_ns[-1]), residual_B, g_B)):
                events += self._reidentify(gone[0], now_ns, gone[1], "weight_step")
        if self.doubt:
            self.doubt.watch_free(self.contact_now, self.drift.offset_S.tolist(), int(est.t_ns[-1]))
        return events

    @property
    def latched(self) -> bool:  # (a latched stop holds the force off until an explicit re-arm)
        return self.bias_hold == "latched"

    def rearm(self, now_ns: int, source: str) -> Event | None:
        """An explicit re-arm from ``source`` (e.g. "key r", "button 0"): its event, None when nothing is latched.

        Granted (``haptic_rearmed``) only while no other reason holds the force off and the estimator no longer
        refuses the newest sample as a contact (free the tool, then re-arm); the force then waits for a settled
        residual. Refused otherwise (``haptic_rearm_refused``, naming why).
        """
        if not self.latched:
            return None
        self.bias_hold = ""
        other = self.reason(now_ns)
        weight = self.hold_cause in (PULL, "tool change")  # (the weight the motion missed: rearm_refusal tells)
        if not other and weight:
            other = rearm_refusal(self.pull_latched_B, self.last_residual, self.label, self.reidentifies_weight)
        elif not other and self.contact_now:
            other = "the estimator still sees a contact (the bias step, or a real one): free the tool"
        if other:
            self.bias_hold = "latched"
            return Event(now_ns, "haptic_rearm_refused", f"re-arm by {source} refused: {other}", {"source": source})
        self.steps, self.bias_hold, self.hold_cause = StepWatch(), "settle", "re-armed"
        self.doubt.close()
        if weight and self.reidentifies_weight is not None:  # (rearm_refusal: None refuses)
            self.reidentifies_weight.reidentify_weight(f"re-armed by {source} after a {PULL}")
            self.hold_until_ns = now_ns + PAYLOAD_HOLD_NS
        self.drift.reset()
        self.lever.reset()
        message = f"haptic force re-armed by {source}; it ramps in from zero once the residual has settled"
        return Event(now_ns, "haptic_rearmed", message, {"source": source})

    def change_tool(self, now_ns: int, how: str, warm: bool) -> list[Event]:
        """Told its tool changed (``how``): the weight and centre of gravity re-identified (``warm``: the new tool's
        saved state given instead, its bias with it), the force held until known (an estimator that cannot: a
        latch); the old stated mass gone, the pull watch afresh. Events ``tool_change`` (``haptic_latched``)."""
        self.stated, self.pull = None, PullWatch()
        self.doubt.close()
        self.drift.reset()
        self.lever.reset()
        self.parameters_known, self.hold_until_ns = False, now_ns + PAYLOAD_HOLD_NS
        event = Event(now_ns, "tool_change", f"{how}: the force is held until the new tool is identified")
        if warm or self.reidentifies_weight is None:
            return [event, *([] if warm else self._latch("tool change", now_ns, f"{self.label} cannot re-identify it"))]
        self.reidentifies_weight.reidentify_weight("tool change")
        return [event]

    def tared(self) -> None:
        """The readings' zero moved (a tare, ``tare.py``): the raw watches afresh, the bias re-identified, held till."""
        assert self.reidentifies is not None  # (a tare is refused to an estimator that cannot)
        self.steps, self.stuck, self.bias_hold, self.hold_cause = StepWatch(), StuckWatch(), "drop", "tare"
        self.drift.reset()  # (no doubt is open: a tare is granted only while nothing holds the force)
        self.lever.reset()
        self.cross.mark(self.last_sample_ns or 0)  # (the step measured from before it)
        self.reidentifies.reidentify_bias("tare")

    def _reidentify(self, step: np.ndarray, now_ns: int, how: str, kind: str = "bias_step") -> list[Event]:
        """A bias step of ``step`` (3,) N (``kind`` "weight_step": a weight step), seen as ``how``: re-identified,
        or the force latches off (the events: ``kind``, and ``haptic_latched`` when latched)."""
        what = self.hold_cause = "sensor bias step" if kind == "bias_step" else "weight step"
        message = f"{what} of {np.linalg.norm(step):.2f} N: {how}"
        self.drift.reset()
        self.lever.reset()
        self.doubt.close()
        if kind == "weight_step" and self.reidentifies_weight is not None:
            self.reidentifies_weight.reidentify_weight(what)
            self.hold_until_ns, self.bias_hold = now_ns + PAYLOAD_HOLD_NS, "settle"  # as after a payload change
            message += f"; {self.label} re-identifies the tool's weight"
        elif kind == "bias_step" and self.reidentifies is not None:
            self.reidentifies.reidentify_bias(what)
            self.bias_hold = "drop"
            message += f"; {self.label} re-identifies its bias"
        else:
            self.bias_hold = "latched"
            message += f"; {self.label} cannot re-identify it: force off until the session is re-armed"
        key = "bias_step_force_S" if kind == "bias_step" else "weight_step_force_B"
        events = [Event(now_ns, kind, message, {key: step.tolist()})]
        if self.bias_hold == "latched":
            events += self._latch(what, now_ns, f"re-arm needed; {self.label} cannot re-identify it")
        return events

    def _latch(self, cause: str, now_ns: int, why: str) -> list[Event]:
        """Latch the force off for ``cause`` until a re-arm: the ``haptic_latched`` event, saying ``why``."""
        self.doubt.close()
        self.bias_hold, self.hold_cause = "latched", cause
        return [Event(now_ns, "haptic_latched", f"haptic force latched off: {cause}: {why}", {"cause": cause})]

    def on_event(self, event: Event, now_ns: int) -> None:
        """A primary estimator's event: a payload change holds the force a while (and ends a pull straight down's
        doubt: the estimator took it as weight); the weight not yet identified goes into the reason."""
        if event.kind == "payload_change":
            self.hold_until_ns = now_ns + PAYLOAD_HOLD_NS
            if self.doubt.kind == PULL:
                self.doubt.close()
        elif event.kind in ("not_identifiable", "identified") and event.data.get("parameter") == "gravity_force_B":
            self.unidentified = event.message if event.kind == "not_identifiable" else ""

    def reason(self, now_ns: int) -> str:
        """Why the force must be zero at ``now_ns`` ("" when it may be on)."""
        if self.last_sample_ns is None or now_ns - self.last_sample_ns > self.stale_timeout_ns:
            return "no sensor data"
        if self.data_reason:
            return self.data_reason
        if poses := self.trust.reason(now_ns):
            return poses
        if self.bias_hold == "latched":
            return f"{self.hold_cause}: re-arm needed"
        if self.bias_hold == "settle":
            size = self.drift.size
            left = f"{size:.2f} N" if math.isfinite(size) else "a window to fill"
            return f"{self.hold_cause}: waiting for the residual to settle ({left})"
        if self.bias_hold:
            return f"{self.hold_cause}: re-identifying"
        if self.doubt:
            return self.doubt.reason()
        unidentified = f" ({self.unidentified})" if self.unidentified else ""
        if not self.ready[0]:
            return f"estimator not converged{unidentified}"
        if (
            self.parameter_std is None
            and self.flags.down_since_ns is not None
            and self.last_sample_ns - self.flags.down_since_ns >= CONVERGENCE_LOSS_NS
        ):
            return "estimator no longer converged"
        if not self.parameters_known:
            return f"parameters not yet identified{unidentified}"
        if self.parameters_lost:
            return "parameters no longer known (uncertainty grew)"
        if self.stated is not None and self.stated.reason:
            return self.stated.reason
        if not self.trust.weight_model:
            return f"{self.label} reports no weight model ({' and '.join(WEIGHT_MODEL)}): the poses cannot be checked"
        if now_ns < self.hold_until_ns:
            return "payload change: tool weight re-identified, holding"
        return self.lever.reason or self.cross.holding

    def fault_event(self, reason: str, now_ns: int) -> Event | None:
        """An event when a new fault starts (a reason that is not the estimator warming up)."""
        fault = reason.split(" (")[0]
        fault = "" if fault in WARMING_UP else fault
        if fault == self.fault:
            return None
        self.fault = fault
        return Event(now_ns, "fault", reason) if fault else None

    def _std(self) -> float | None:
        if self.parameter_std is None:
            return None
        values = self.parameter_std.force_parameter_std().tolist()  # six values: Python's max beats numpy's call
        return math.nan if any(map(math.isnan, values)) else max(values)  # (NaN when any is)
