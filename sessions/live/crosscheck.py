"""The second channel: the robot's own measure of the contact force against the wrist sensor's.

A UR e-Series arm measures the wrench on its tool itself (``actual_TCP_force``, the payload's weight taken
out by its controller): coarse (the UR5e states 4 N per axis), but independent of the wrist sensor, its
bias and hapticlab's estimators. Where the kinematics ``MeasuresWrench``, :class:`WrenchCrossCheck` keeps
both channels as means over ``drift.BIN_NS`` (20 ms) bins, in the base frame B, and compares each bin:

* **disagreement**: the estimator's contact force and the robot's differ by more than the robot's stated
  accuracy on an axis, in ``DISAGREE_BINS`` consecutive bins. Which one is wrong the two cannot say (a bias
  step, a spike, a stuck channel on the sensor's side; a wrong payload set on the arm on the other), so the
  force is held at zero until they have agreed for ``AGREE_NS``; a robot's wrench that stops coming while the
  sensor's does holds it too (the check cannot run);
* **confirmation**: a sudden step (``watch.StepWatch``) that the robot's force shows too, within
  ``CONFIRM_BINS``, by at least ``CONFIRM_N``, matching the sensor's step (``STEP_MATCH_N``) and leaving the
  robot's force beyond its accuracy along the step, is a contact (a collision): the gate renders it at once
  instead of waiting half a second for the motion to tell. (A contact that ended is no confirmation: a tool
  lifted off what it started resting on steps both channels alike, and only the robot's zero, known to 4 N,
  could tell.)

Comparing bin means rather than samples takes the robot's noise (0.6 N, 1σ, in the simulated UR5e) down to
about 0.2 N, and waits at most a bin and the robot's latency for a verdict.
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.core.types import PoseSample
from hapticlab.sessions.live.drift import BIN_NS

DISAGREE_BINS = 2
"""Consecutive bins that must disagree before the force is held (40 ms): a real arm's wrench lags the wrist
sensor's by its filter, so a collision's first bin may disagree."""
AGREE_NS = 200_000_000
"""After a disagreement the channels must agree this long (ten bins) before the force may come back, ns: a
fault that flickers (a loose connector) keeps the force off rather than on and off."""
CONFIRM_N = 1.5
"""A sudden step the robot's force shows by at least this much, N, is a contact: about eight times its bin
mean's noise (norm), and more than its offset can move in a second."""
STEP_MATCH_N = 1.0
STEP_MATCH_SHARE = 0.25
"""...and matches the sensor's step within this, N per axis, plus this share of the sensor's step: the robot's
offset cancels in a step, its bin noise does not (0.3 N per axis) and its filter may lag a bin. Looser, a
bias step landing while a contact grows would pass for the contact (a 3 N step beside a 1.5 N push misses by
3 N, over 1 + 0.25·4.5)."""
CONFIRM_BINS = 5
"""...within this many bins of the step (100 ms: the robot's filter and latency; later, the step is old news and
the contact's own rise or end would pass for it)..."""
MARK_KEEP_BINS = 15
"""A mark within this many bins of the last keeps its reference (300 ms: a jump held out for 200 ms, then
kept, is one step)."""
KEEP_BINS = 8
"""Bins kept per channel waiting for the other's (160 ms: more than the robot's latency)."""


class _Bins:
    """One channel's 20 ms means: the bin being filled, and the completed ones by bin index."""

    def __init__(self) -> None:
        self.bin = -1
        self.sum = [0.0, 0.0, 0.0]
        self.count = 0
        self.done: dict[int, list[float]] = {}

    def add(self, b: int, f: list[float]) -> None:
        """One force (3,) N in bin ``b``: a later bin completes the one being filled."""
        if b != self.bin:
            if self.count:
                self.done[self.bin] = [x / self.count for x in self.sum]
                if len(self.done) > KEEP_BINS:
                    del self.done[min(self.done)]
            self.bin, self.sum, self.count = b, [0.0, 0.0, 0.0], 0
        s = self.sum
        s[0] += f[0]
        s[1] += f[1]
        s[2] += f[2]
        self.count += 1


class WrenchCrossCheck:
    """The estimator's contact force against the robot's own, bin by bin (module docstring).

    Args:
        accuracy_N: the robot's stated force accuracy, N per axis (``MeasuresWrench.wrench_accuracy_N``; 0: the
            robot reports no wrench, and the check idles).
    """

    def __init__(self, accuracy_N: float):
        self.accuracy_N = float(accuracy_N)
        self.robot, self.sensor = _Bins(), _Bins()
        self.compared = -1  # the newest bin compared
        self.holding = ""  # why the force is held ("" agreeing)
        self.agree_since_ns: int | None = None
        self.disagreements = 0  # bins that disagreed, in the session
        self.reference: tuple[list[float], list[float]] | None = None  # (robot, sensor) before a sudden step
        self.marked = self.window_from = -1  # the bins of the step's first mark and of the last (at their time)
        self.confirmed = ""  # the newest bin confirmed the step: how ("" not)
        self.step_B = [0.0, 0.0, 0.0]  # the sensor's step the robot's confirmed, N in B
        self.bad_bins = 0  # consecutive compared bins that disagreed
        self.origin_ns: int | None = None  # bin 0 starts at the first stamp either channel brought

    def _bin(self, t_ns: int) -> int:
        """The bin of ``t_ns``, counted from the first stamp (so a session's bins do not depend on its clock)."""
        if self.origin_ns is None:
            self.origin_ns = t_ns
        return (t_ns - self.origin_ns) // BIN_NS

    def add_robot(self, poses: list[PoseSample]) -> None:
        """The robot's wrench of each new pose (a pose without one, or a non-finite one, is skipped)."""
        if self.accuracy_N <= 0:
            return
        for pose in poses:
            w = pose.wrench_B
            if w is not None:
                f = w[:3].tolist()
                if math.isfinite(f[0] + f[1] + f[2]):
                    self.robot.add(self._bin(pose.t_ns), f)
        self._compare()

    def add_contact(self, t_ns: np.ndarray, contact_force_S: np.ndarray, R_EB: np.ndarray, R_SE) -> None:
        """The estimator's contact force (N, 3) N in S at ``t_ns``, turned into B with the poses (N, 3, 3)."""
        if self.accuracy_N <= 0:
            return
        force_E = contact_force_S if R_SE is None else contact_force_S @ R_SE
        force_B = np.einsum("nji,nj->ni", R_EB, force_E).tolist()
        for t, f in zip(t_ns.tolist(), force_B):
            if math.isfinite(f[0] + f[1] + f[2]):
                self.sensor.add(self._bin(t), f)
        self._compare()

    def mark(self, t_ns: int) -> None:
        """A step may be under way at ``t_ns`` (a jump held out, a sudden step): it is measured from the newest
        compared bin, or from the one an earlier mark took within ``MARK_KEEP_BINS`` (a jump held out, then kept),
        and may be confirmed by the bins within ``CONFIRM_BINS`` of this mark."""
        now = self.window_from = self._bin(t_ns)
        if self.reference is None or now - self.marked > MARK_KEEP_BINS:
            self.marked, b = now, self.compared
            known = b in self.robot.done and b in self.sensor.done  # (a channel silent since: no reference)
            self.reference = (self.robot.done[b], self.sensor.done[b]) if known else None
        self.confirmed = ""

    def _compare(self) -> None:
        robot, sensor = self.robot.done, self.sensor.done
        for b in sorted(sensor):
            if b <= self.compared or b not in robot:
                continue
            if b != self.compared + 1:  # bins between never compared: they are no agreement
                self.agree_since_ns, self.bad_bins = None, 0
            self.compared = b
            r, s = robot[b], sensor[b]
            worst = max(range(3), key=lambda i: abs(s[i] - r[i]))
            off = s[worst] - r[worst]
            end_ns = (b + 1) * BIN_NS
            self.bad_bins = self.bad_bins + 1 if abs(off) > self.accuracy_N else 0
            if self.bad_bins >= DISAGREE_BINS:
                self.disagreements += 1
                self.agree_since_ns = None
                self.holding = (
                    f"wrist sensor and robot disagree (the contact force is {off:+.1f} N off the robot's own on "
                    f"{'xyz'[worst]}, beyond its {self.accuracy_N:g} N accuracy)"
                )
            elif self.holding and not self.bad_bins:
                if self.agree_since_ns is None:
                    self.agree_since_ns = end_ns - BIN_NS
                if end_ns - self.agree_since_ns >= AGREE_NS:
                    self.holding = ""
            if self.reference is not None and not self.confirmed and b <= self.window_from + CONFIRM_BINS:
                self.confirmed = self._confirms(r, s)
        if self.sensor.bin - max(self.compared, self.robot.bin) > KEEP_BINS:  # the robot's wrench stopped coming
            self.agree_since_ns, self.bad_bins = None, 0
            self.holding = (
                f"robot's own wrench missing (none for {KEEP_BINS * BIN_NS * 1e-6:.0f} ms while the sensor's came: "
                "the cross-check cannot run)"
            )

    def _confirms(self, r: list[float], s: list[float]) -> str:
        """How the step from the reference to bin means ``r`` (robot) and ``s`` (sensor) is a contact ("" not)."""
        assert self.reference is not None
        robot_step = [r[i] - self.reference[0][i] for i in range(3)]
        sensor_step = [s[i] - self.reference[1][i] for i in range(3)]
        size = math.sqrt(sum(x * x for x in robot_step))
        match = STEP_MATCH_N + STEP_MATCH_SHARE * math.sqrt(sum(x * x for x in sensor_step))
        if size < CONFIRM_N or any(abs(robot_step[i] - sensor_step[i]) > match for i in range(3)):
            return ""
        if sum(r[i] * robot_step[i] for i in range(3)) < self.accuracy_N * size:  # the robot's force, along the step
            return ""  # (a contact that ended, or one the robot cannot tell from its own zero: no contact to confirm)
        self.step_B = sensor_step  # (the sensor's: the robot's noise turns a small step's direction)
        return f"the robot's own force stepped {size:.1f} N with it"
