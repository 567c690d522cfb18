"""The ``axial_rotation`` motion script: the tool held horizontal and turned about its own axis.

Frames: B robot base, E flange. ``R_BE`` maps vectors from E into B.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hapticlab.core.frames import skew
from hapticlab.core.host.options import OptionError, number
from hapticlab.plugins.simworld.motion.script import (
    HORIZONTAL_R_BE,
    DEFAULT_P_BoEo_B,
    MotionScript,
    MotionState,
    as_times,
    quintic,
    rodrigues,
)

__all__ = ["AxialRotation"]


class AxialRotation(MotionScript):
    """The tool held horizontal and turned about its own axis (the paper's 104 g test).

    ``R_BE(t) = HORIZONTAL_R_BE · Rot_z(roll0 + φ(t))``: E's z axis lies along +x
    of B, and E turns about it. The angle φ(t):

    * rest until ``start_s``;
    * ramp up during ``ramp_s``: φ̇ = speed · s(τ) with the quintic s, so the
      angular acceleration rises and falls smoothly (peak 1.875·speed/ramp_s);
    * constant speed;
    * ramp down (mirror of the ramp up), then hold.

    Each ramp turns the tool by speed·ramp_s/2. With ``turns`` the total angle
    is 2π·turns; with ``duration`` (s, from the start of the ramp up to the end
    of the ramp down) the total angle is speed·(duration − ramp_s). Neither
    given: one turn.

    Parameters
    ----------
    speed_deg_s : rotation speed, deg/s (negative turns the other way).
    duration : time from start to stop, ramps included, s.
    turns : number of full turns (alternative to ``duration``).
    ramp_s : duration of each speed ramp, s (> 0).
    start_s : rest before the rotation starts, s.
    roll0_deg : starting roll about the tool axis, degrees.
    p_BoEo_B : (3,) flange position in B, m.
    """

    name = "axial_rotation"

    def __init__(
        self,
        speed_deg_s: float = 30.0,
        duration: float | None = None,
        turns: float | None = None,
        ramp_s: float = 0.2,
        start_s: float = 0.0,
        roll0_deg: float = 0.0,
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
    ):
        if duration is not None and turns is not None:
            raise OptionError("turns", "give either duration or turns, not both")
        if number("speed_deg_s", speed_deg_s, hint=" (deg/s)") == 0:
            raise OptionError("speed_deg_s", "must be a finite number other than 0 (deg/s), got 0")
        number("ramp_s", ramp_s, above=0, hint=" (s)")
        number("start_s", start_s, minimum=0, hint=" (s)")
        self.speed = np.deg2rad(float(speed_deg_s))  # rad/s
        self.ramp_s = float(ramp_s)
        self.start_s = float(start_s)
        self.roll0 = np.deg2rad(float(roll0_deg))
        self.p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)
        if duration is None:
            angle = 2.0 * np.pi * (1.0 if turns is None else float(turns))
            longest_ramp_s = angle / abs(self.speed)
            self.cruise_s = angle / abs(self.speed) - self.ramp_s
        else:
            longest_ramp_s = float(duration) / 2.0
            self.cruise_s = float(duration) - 2.0 * self.ramp_s
        if self.cruise_s < 0:
            raise OptionError(
                "ramp_s",
                f"must be <= {longest_ramp_s:g} s: the rotation is too short for its two speed ramps "
                f"(lower ramp_s or raise duration or turns), got {ramp_s!r}",
            )
        # HORIZONTAL_R_BE [z]× and HORIZONTAL_R_BE [z]×²: Rot_z by Rodrigues' formula (see rodrigues)
        z_cross = skew(np.array([0.0, 0.0, 1.0]))
        self._R_BE_0_n = HORIZONTAL_R_BE @ z_cross
        self._R_BE_0_nn = self._R_BE_0_n @ z_cross

    @property
    def end_s(self) -> float:
        """Time at which the tool comes to rest again, s."""
        return self.start_s + 2.0 * self.ramp_s + self.cruise_s

    @property
    def total_angle(self) -> float:
        """Signed total rotation about the tool axis, rad."""
        return self.speed * (self.ramp_s + self.cruise_s)

    def angle(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotation angle φ (rad) and its first two derivatives at times ``t`` (s)."""
        t = as_times(t)
        w0, T = self.speed, self.ramp_s
        since_start = t - self.start_s
        # Both ramps at once, (N, 2): time into the ramp up and into the ramp down, in ramps
        u = np.empty((len(t), 2))
        u[:, 0] = since_start / T
        u[:, 1] = (since_start - T - self.cruise_s) / T
        u_clipped = np.minimum(np.maximum(u, 0.0), 1.0)
        # ∫₀^u s(v) dv for the quintic s: 2.5u⁴ − 3u⁵ + u⁶ (equals 1/2 at u = 1).
        s_integral = u_clipped**4 * (2.5 - 3.0 * u_clipped + u_clipped**2)
        s, ds, _ = quintic(u)
        # Speed: w0 · (s_up − s_down); the cruise is the plateau in between.
        phi_dot = w0 * (s[:, 0] - s[:, 1])
        phi_ddot = w0 * (ds[:, 0] - ds[:, 1]) / T
        cruise_time = np.minimum(np.maximum(since_start - T, 0.0), self.cruise_s)
        phi = w0 * (T * s_integral[:, 0] + cruise_time + T * (u_clipped[:, 1] - s_integral[:, 1]))
        return phi, phi_dot, phi_ddot

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        t = as_times(t)
        phi, phi_dot, phi_ddot = self.angle(t)
        n = len(t)
        z = np.zeros((n, 3))
        w = z.copy()
        w[:, 2] = phi_dot
        alpha = z.copy()
        alpha[:, 2] = phi_ddot
        return MotionState(
            t=t,
            R_BE=rodrigues(HORIZONTAL_R_BE, self._R_BE_0_n, self._R_BE_0_nn, self.roll0 + phi),
            p_BoEo_B=np.broadcast_to(self.p_BoEo_B, (n, 3)).copy(),
            w_BE_E=w,
            alpha_BE_E=alpha,
            v_BEo_B=z,
            a_BEo_B=z.copy(),
        )
