"""The safety-critical end: turns a contact estimate into a device force command.

On any doubt (the gate in ``gate.py`` says which) the command is zero at once,
with the reason. Otherwise, in this order:

1. **map** the contact force from the sensor frame S into the device base D:
   ``force_D = scale · R_DB · R_BS · contact_force_S`` with ``R_BS = R_BE · R_ES``
   (the flange's orientation from the kinematics, the sensor's mount);
2. **deadband**: a force smaller than ``deadband`` is zero, a larger one loses
   ``deadband`` from its magnitude, direction kept (continuous: no step);
3. **low-pass**: first order, cut-off ``cutoff_hz``, discretised exactly for
   the device period T: ``y ← y + (1 − e^(−2π·fc·T))·(x − y)``, so a step
   reaches 1 − e^(−n·T/τ) after n periods (τ = 1/(2π·fc));
4. **clamp** the magnitude to ``max_force`` and the device's own limit
   (``HasForceLimit``), direction kept;
5. **slew-rate limit**: at most ``max_force_rate · T`` from the last command
   (and never above the limit: a limit that falls below the last command, a
   device lowering its maximum, brings the force down to it at once).

Going to zero is never rate-limited; coming back from zero is (the ramp
starts at zero), and a zero for a reason also empties the low-pass, so a force
that comes back never replays what the filter held before.

The governor checks its *output*, not only its input: a command that is not
finite, above the limit, or more than one rate-limited step from the last one
(a finite but huge reading overflows in the rotation) is replaced by zero with
the reason, so nothing else ever reaches the device.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from hapticlab.core.frames import matrix_from_rotvec
from hapticlab.core.types import HapticCommand
from hapticlab.sessions.settings import HapticSettings

ZERO3 = np.zeros(3)
TOLERANCE = 1e-9
"""Relative slack of the output checks (rounding of the arithmetic that enforces them)."""


def deadband(force: np.ndarray, width: float) -> np.ndarray:
    """(3,) ``force`` with ``width`` (N) taken off its magnitude, zero when it is smaller; direction kept."""
    return np.array(_deadband3(width, *force.tolist()))


def _deadband3(width: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """:func:`deadband` on three floats (the governor's arithmetic is in Python floats: at one vector per
    device period numpy's per-call cost is most of the work)."""
    norm = math.hypot(x, y, z)
    if norm <= width:
        return 0.0, 0.0, 0.0
    k = (norm - width) / norm
    return x * k, y * k, z * k


def lowpass_gain(cutoff_hz: float, period_s: float) -> float:
    """The exact first-order gain 1 − e^(−2π·fc·T) for a cut-off ``cutoff_hz`` (Hz) and period ``period_s`` (s).

    1 (no filtering) when the cut-off is 0 (off).
    """
    if cutoff_hz <= 0:
        return 1.0
    return -math.expm1(-2.0 * math.pi * cutoff_hz * period_s)


class ForceGovernor:
    """Maps, filters, clamps and rate-limits contact forces for the haptic device.

    Args:
        settings: limits and the device mapping (the ``[haptic]`` table).
        period_s: the device command period, s (for the filter and the rate limit).

    Attributes:
        R_DB: (3, 3) orientation of the robot base B in the device base D.
        max_step: largest change of the command in one period, N.
        gain: the low-pass's gain per period (1: off).
        device_max_force: the device's own force limit, N (None: it reports none);
            the loop sets it from a ``HasForceLimit`` output before each command.
        filtered_D: (3,) the low-pass's state, N in D.
        last_force_D: (3,) the last command's force, N in D.
    """

    def __init__(self, settings: HapticSettings, period_s: float):
        self.settings = settings
        self.R_DB = matrix_from_rotvec(np.asarray(settings.rotation_DB, dtype=float))
        self.max_step = settings.max_force_rate * period_s
        self.gain = lowpass_gain(settings.cutoff_hz, period_s)
        self.device_max_force: float | None = None
        # the arithmetic's own copies, in Python floats (numpy's per-call cost is most of the work at one vector
        # per device period): R_DB's rows, the low-pass state and the last command
        self._R_DB_rows = tuple(tuple(row) for row in self.R_DB.tolist())
        self._filtered: list[float] = [0.0, 0.0, 0.0]
        self._last: list[float] = [0.0, 0.0, 0.0]

    @property
    def filtered_D(self) -> np.ndarray:
        """(3,) the low-pass's state, N in D."""
        return np.array(self._filtered)

    @property
    def last_force_D(self) -> np.ndarray:
        """(3,) the last command's force, N in D."""
        return np.array(self._last)

    def limit(self) -> float:
        """The force limit in use, N: ``max_force``, or the device's own when smaller (NaN when it is unusable)."""
        device = self.device_max_force
        if device is None:
            return self.settings.max_force
        if not (math.isfinite(device) and device > 0):
            return math.nan
        return min(self.settings.max_force, float(device))

    def command(
        self,
        t_ns: int,
        contact_force_S: np.ndarray | None,
        R_BS: np.ndarray | None,
        reason: str = "",
        source_t_ns: int | None = None,
        port: Callable[[list[float]], list[float]] | None = None,
    ) -> HapticCommand:
        """The command for this device period; ``reason`` non-empty forces zero.

        Args:
            t_ns: the command's time, ns.
            contact_force_S: (3,) the contact force in the sensor frame S, N.
            R_BS: (3, 3) orientation of S in the robot base B (R_BE·R_ES: the flange's
                orientation and the sensor's mount, identity unless an estimator knows it).
            reason: why the force must be zero ("" when it may be on).
            source_t_ns: stamp of the sensor sample the contact force was estimated from, ns.
            port: what the haptic port adds to the filtered force (D, N) before the clamp, the rate limit and the
                output check (teleoperation's passivity controller: its damping is a force like any other).
        """
        limit = self.limit()
        if not reason and not math.isfinite(limit):
            reason = f"haptic device reports no usable force limit ({self.device_max_force!r} N)"
        if not reason and (contact_force_S is None or R_BS is None):
            reason = "no estimate yet"
        if not reason:
            assert contact_force_S is not None  # else the reason is "no estimate yet"
            f0, f1, f2 = contact_force_S.tolist()
            if not (math.isfinite(f0) and math.isfinite(f1) and math.isfinite(f2)):
                reason = "non-finite contact force"
        if not reason:  # Python floats: an overflow gives inf, no warning, and fails the check
            scale = self.settings.scale
            # R_BS · f, then R_DB · that, in Python floats (numpy's 3×3 product costs more than its 18 products)
            assert R_BS is not None  # else the reason is "no estimate yet"
            force_B = [r0 * f0 + r1 * f1 + r2 * f2 for r0, r1, r2 in R_BS.tolist()]
            b0, b1, b2 = force_B
            mapped_D = [scale * (r0 * b0 + r1 * b1 + r2 * b2) for r0, r1, r2 in self._R_DB_rows]
            if not math.isfinite(math.hypot(*mapped_D)):
                reason = "non-finite force after the mapping"
        if reason:
            return self._zero(t_ns, reason)
        # a convex combination of finite forces: the filter's state stays finite
        gain = self.gain
        x0, x1, x2 = _deadband3(self.settings.deadband, *mapped_D)
        y0, y1, y2 = self._filtered
        self._filtered = target = [y0 + gain * (x0 - y0), y1 + gain * (x1 - y1), y2 + gain * (x2 - y2)]
        if port is not None:
            target = port(target)
        norm = math.hypot(*target)
        if norm > limit:
            target = [v * (limit / norm) for v in target]
        last = self._last
        step = [target[0] - last[0], target[1] - last[1], target[2] - last[2]]
        step_norm = math.hypot(*step)
        if step_norm > self.max_step:
            target = [w + d * (self.max_step / step_norm) for w, d in zip(last, step)]
            norm = math.hypot(*target)
            if norm > limit:  # the limit fell below the last command (a device lowered it): down at once
                target = [v * (limit / norm) for v in target]
        norm = math.hypot(*target)
        if not (
            math.isfinite(norm)
            and norm <= limit * (1 + TOLERANCE)
            and (
                math.hypot(target[0] - last[0], target[1] - last[1], target[2] - last[2])
                <= self.max_step * (1 + TOLERANCE)
                or norm < math.hypot(*last)
            )
        ):
            return self._zero(t_ns, "governor output out of bounds")  # unreachable by the arithmetic above
        self._last = target  # (never changed in place)
        return HapticCommand(t_ns, np.array(target), True, "", source_t_ns)

    def _zero(self, t_ns: int, reason: str) -> HapticCommand:
        """A zero command for ``reason``; the filter and the ramp start again from zero."""
        self._filtered = self._last = [0.0, 0.0, 0.0]
        return HapticCommand(t_ns, ZERO3, False, reason)
