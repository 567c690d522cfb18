"""May the robot's poses be paired with the wrench: not frozen, not just jumped, not out of step with it.

The gate's checks of the kinematics, in one place: :class:`PoseTrust` keeps the pose watch (frozen, jumped:
``watch.PoseWatch``) and the lag watch (out of step: ``watch.LagWatch``, which needs the estimator's weight
model to check the poses against the wrench). When the poses are not trusted the samples are kept from the
estimators (which would learn the fault into their parameters) and the force is held, the reason naming the
kinematics.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.host.interfaces import WEIGHT_MODEL
from hapticlab.core.types import AlignedSamples, PoseSample
from hapticlab.sessions.live.watch import LAG_LIMIT_S, LagWatch, PoseWatch

JUMP_HOLD_NS = 500_000_000
"""After the poses jump the force is held at zero this long (0.5 s): long enough for the lag watch, started
afresh, to resolve a lag while the tool turns fast enough for the lag to matter."""


class PoseTrust:
    """The pose and lag watches (module docstring); ``weight_model`` False once the estimator's parameters
    lack one (``WEIGHT_MODEL``): the poses cannot be checked then."""

    def __init__(self, frozen_pose_timeout_ns: int, max_turn_rate: float, max_speed: float, weight_model: bool):
        self.poses = PoseWatch(frozen_pose_timeout_ns, max_turn_rate, max_speed)
        self.lag = LagWatch(max_turn_rate)
        self.weight_model = weight_model

    def frozen(self) -> bool:
        """The robot's poses are frozen now (their samples must not reach the estimators)."""
        return self.poses.frozen_for_ns > 0

    def jumped(self, now_ns: int) -> bool:
        return self.poses.jump is not None and now_ns - self.poses.jump[0] < JUMP_HOLD_NS

    def out_of_step(self) -> bool:
        return self.lag.lag_s is not None and abs(self.lag.lag_s) > LAG_LIMIT_S

    def trusted(self, now_ns: int) -> bool:
        return not (self.frozen() or self.jumped(now_ns) or self.out_of_step())

    def add_poses(self, poses: list[PoseSample], now_ns: int) -> None:
        """New poses arrived at ``now_ns``: a jump starts the lag watch afresh."""
        if self.poses.add(poses, now_ns):
            self.lag.reset()

    def watch_lag(self, block: AlignedSamples, params: dict[str, list[float]], R_SE: np.ndarray | None) -> None:
        """Feed the lag watch, with the estimator's weight model; without one the poses cannot be checked."""
        if all(key in params for key in WEIGHT_MODEL):
            self.lag.add(block, params, R_SE)
        else:
            self.weight_model = False

    def reason(self, now_ns: int) -> str:
        """Why the poses may not be trusted at ``now_ns`` ("" they may)."""
        if self.frozen():
            return f"kinematics frozen (the same pose for {self.poses.frozen_for_ns * 1e-6:.0f} ms)"
        if self.jumped(now_ns):
            assert self.poses.jump is not None  # jumped: a jump was seen
            return f"kinematics jumped ({self.poses.jump[1]})"
        if self.out_of_step():
            lag_ms = (self.lag.lag_s or 0.0) * 1e3  # (a lag was measured)
            late = "late" if lag_ms > 0 else "early"
            return f"kinematics out of step with the sensor (poses {abs(lag_ms):.0f} ms {late})"
        return ""
