"""The primary estimator's convergence flags, stage by stage, as the haptic gate reads them.

Per stage (force, torque): whether it has converged at least once (``ready``), its flag after the newest
sample (``converged``), how often the flag flipped (``flips``, recorded in the session summary), and for
the force stage since when its flag has been down (``down_since_ns``): Algorithm 1's flag flickers while
the estimate still settles, so the gate counts a force stage as no longer converged only once its flag has
been down for a while (``gate.CONVERGENCE_LOSS_NS``).
"""

from __future__ import annotations

from hapticlab.core.types import Estimates, Event


class ConvergenceFlags:
    """The flags of one estimator's blocks, in time order (module docstring); ``label`` names it in events."""

    def __init__(self, label: str):
        self.label = label
        self.ready = [False, False]  # each stage has converged at least once
        self.converged = [False, False]  # each stage's flag after the last sample
        self.down_since_ns: int | None = None  # the force stage's flag has been down since (None: it is up)
        self.flips = [0, 0]

    def add(self, est: Estimates) -> list[Event]:
        """One block's flags: the ``converged`` event of a stage's first convergence, at its sample."""
        events = []
        for stage, flags, name in ((0, est.converged_force, "force"), (1, est.converged_torque, "torque")):
            flags = flags.tolist()  # a live block is a few samples: Python's bools beat numpy's calls here
            previous = self.converged[stage]
            for flag in flags:
                self.flips[stage] += flag != previous
                previous = flag
            self.converged[stage] = previous
            if stage == 0:
                self._track_flag(est.t_ns.tolist(), flags)
            if not self.ready[stage] and True in flags:
                self.ready[stage] = True
                k = flags.index(True)
                events.append(Event(int(est.t_ns[k]), "converged", f"{self.label} {name} stage converged"))
        return events

    def _track_flag(self, t_ns: list[int], flags: list[bool]) -> None:
        """Keep when the force stage's flag went down, for the trailing run of samples it has been down."""
        if flags[-1]:
            self.down_since_ns = None
            return
        up = len(flags) - flags[::-1].index(True) - 1 if True in flags else -1  # the last sample with it up
        if up >= 0 or self.down_since_ns is None:
            self.down_since_ns = int(t_ns[up + 1])
