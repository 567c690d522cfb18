"""The haptic gate: at every tick, may the contact force reach the trainee's hand, and if not, why not.

The force is held at zero (the reason is recorded with each command) while:

* the newest sensor sample is older than the stale timeout ("no sensor data");
* the newest block had stale kinematics, a sensor status bit or a non-finite reading;
* the estimator's force stage has not converged yet;
* its force-stage parameters are not yet known to ``ready_force_std`` (for an
  estimator that reports their std), or are no longer (the std grew back);
* an estimator event said the tool's weight changed (held ``PAYLOAD_HOLD_NS``).

Algorithm 1 recomputes its flag at every update, so after the first
convergence it flickers with noise; the gate waits for the first convergence
("ready") and counts the flips instead of making each one an event.
"""

from __future__ import annotations

import numpy as np

from ...core.interfaces import ReportsParameterStd
from ...core.types import STATUS_OK, AlignedSamples, Estimates, Event

STD_CHECK_NS = 10_000_000
"""After the force parameters were first known to ready_force_std, their std is checked again this
often (10 ms): above the bound again (a drifting estimator through a long contact) zeroes the force."""
PAYLOAD_HOLD_NS = 1_000_000_000
"""After an estimator's payload change the haptic force is held at zero this long (1 s): the change
may be a load held by the tool (a grasped object) rather than a new tool, and its release would then
show as a phantom force until the estimator sees the second change."""


def data_reason(block: AlignedSamples, usable: np.ndarray) -> str:
    """What was wrong with a block of aligned samples ("" when every sample is usable)."""
    if usable.all():
        return ""
    if block.stale.any():
        return "stale kinematics"
    if (block.status != STATUS_OK).any():
        return "sensor saturated or in error"
    return "non-finite sensor reading"


class HapticGate:
    """Tracks the primary estimator's readiness and tells the loop why the force must be zero.

    Args:
        label: the estimator's label, for event messages.
        ready_force_std: the force-stage parameters' std below which the force may go on, N.
        parameter_std: the estimator when it reports that std (else None: convergence alone decides).
        stale_timeout_ns: oldest newest-sample age before "no sensor data", ns.
    """

    def __init__(self, label: str, ready_force_std: float, parameter_std: ReportsParameterStd | None,
                 stale_timeout_ns: int):
        self.label = label
        self.ready_force_std = ready_force_std
        self.parameter_std = parameter_std
        self.stale_timeout_ns = stale_timeout_ns
        self.ready = [False, False]  # each stage has converged at least once
        self.converged = [False, False]  # each stage's flag after the last sample
        self.flips = [0, 0]
        self.parameters_known = False
        self.parameters_lost = False
        self.next_std_check_ns = 0
        self.hold_until_ns = 0
        self.last_sample_ns: int | None = None
        self.data_reason = ""

    def on_samples(self, block: AlignedSamples, usable: np.ndarray) -> None:
        """A new sensor block arrived (every sample, usable or not)."""
        self.last_sample_ns = int(block.t_ns[-1])
        self.data_reason = data_reason(block, usable)

    def on_estimates(self, est: Estimates, now_ns: int) -> list[Event]:
        """The primary estimator's output for the usable samples: the events it makes (first convergence...)."""
        events = []
        for stage, flags, name in ((0, est.converged_force, "force"), (1, est.converged_torque, "torque")):
            self.flips[stage] += int(np.count_nonzero(np.diff(flags, prepend=self.converged[stage])))
            self.converged[stage] = bool(flags[-1])
            if not self.ready[stage] and flags.any():
                self.ready[stage] = True
                k = int(np.argmax(flags))
                events.append(Event(int(est.t_ns[k]), "converged", f"{self.label} {name} stage converged"))
        if self.ready[0] and not self.parameters_known:
            std = self._std()
            self.parameters_known = std is None or std <= self.ready_force_std
            if self.parameters_known and std is not None:
                events.append(Event(now_ns, "parameters_known", f"force parameters known to ±{std:.3g} N (1σ)"))
        elif self.parameters_known and self.parameter_std is not None and now_ns >= self.next_std_check_ns:
            self.next_std_check_ns = now_ns + STD_CHECK_NS  # a drifting estimator's std grows in a long contact
            self.parameters_lost = self._std() > self.ready_force_std
        return events

    def on_event(self, event: Event, now_ns: int) -> None:
        """An event of the primary estimator: a payload change holds the force at zero for a while."""
        if event.kind == "payload_change":
            self.hold_until_ns = now_ns + PAYLOAD_HOLD_NS

    def reason(self, now_ns: int) -> str:
        """Why the force must be zero at ``now_ns`` ("" when it may be on)."""
        if self.last_sample_ns is None or now_ns - self.last_sample_ns > self.stale_timeout_ns:
            return "no sensor data"
        if self.data_reason:
            return self.data_reason
        if not self.ready[0]:
            return "estimator not converged"
        if not self.parameters_known:
            return "parameters not yet identified"
        if self.parameters_lost:
            return "parameters no longer known (uncertainty grew)"
        if now_ns < self.hold_until_ns:
            return "payload change: tool weight re-identified, holding"
        return ""

    def _std(self) -> float | None:
        if self.parameter_std is None:
            return None
        return float(np.max(self.parameter_std.force_parameter_std()))
