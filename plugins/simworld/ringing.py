"""A ringing tool: a lightly damped oscillation after each stop of the motion.

A slender instrument (a long shaft, a loosely clamped adapter) is not rigid: its far part is a mass ``m`` on a
spring of natural frequency ``f`` and damping ratio ζ. When the robot stops within a fraction of that period,
the part keeps the velocity ``v`` it had and swings about its rest: a free damped oscillation, whose spring
force on the sensor is, with ω = 2πf, ω_d = ω√(1 − ζ²) and τ the time since the stop::

    f_B(τ) = m · ω²/ω_d · v · exp(−ζωτ) · sin(ω_d τ)      (τ ≥ 0; v the point's velocity in B)

(the spring force k·x of x(τ) = v/ω_d · exp(−ζωτ) sin(ω_d τ), k = mω²), summed over the stops. The stops and
the velocities come from the motion script (:meth:`Ringing.after_stops`): a stop is where the point's speed
falls below 1 % of the peak of the move before it, and the velocity is the one at that peak (the robot's own
deceleration taken as abrupt: idealised, and the ringing's largest case). The world treats it as a force at
``point_S`` like a contact (the truth's ``contact`` flag is set while it rings); the sensor reads it like any
other load.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hapticlab.core.host.options import check, check_fields, number, vector

__all__ = ["Ringing"]


@dataclass(frozen=True, slots=True)
class Ringing:
    """The damped swing of a tool's flexible part after each stop (see the module docstring).

    Attributes:
        stops_s: (k,) the instants the motion stops, s.
        velocity_B: (k, 3) the point's velocity the swing starts with at each stop, in B, m/s.
        frequency_hz: the part's natural frequency f, Hz (> 0).
        damping_ratio: ζ, in [0, 1) (0.02-0.1 for a metal shaft).
        mass: the swinging part's effective mass m, kg (> 0).
        point_S: (3,) where its spring force acts on the tool, in S, m; None: the tool tip.
        duration_s: how long after a stop the swing is followed (the envelope is then e⁻¹⁰ of its start), s;
            None: 10/(ζ·2πf), or 10 s at ζ = 0.
    """

    stops_s: np.ndarray
    velocity_B: np.ndarray
    frequency_hz: float = 6.0
    damping_ratio: float = 0.03
    mass: float = 0.05
    point_S: np.ndarray | None = None
    duration_s: float | None = None

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "frequency_hz": check(number, above=0, hint=" (Hz)"),
                "damping_ratio": check(number, minimum=0, maximum=0.99, hint=""),
                "mass": check(number, above=0, hint=" (kg)"),
            },
        )
        object.__setattr__(self, "stops_s", np.asarray(self.stops_s, dtype=float).reshape(-1))
        object.__setattr__(self, "velocity_B", np.asarray(self.velocity_B, dtype=float).reshape(-1, 3))
        if self.point_S is not None:
            object.__setattr__(self, "point_S", vector("point_S", self.point_S))
        if self.duration_s is None:
            zeta_w = self.damping_ratio * 2 * math.pi * self.frequency_hz
            object.__setattr__(self, "duration_s", 10.0 / zeta_w if zeta_w > 0 else 10.0)

    @classmethod
    def after_stops(
        cls, motion, until_s: float, point_E=(0.0, 0.0, 0.25), grid_s: float = 1e-3, min_speed: float = 0.01, **params
    ) -> Ringing:
        """The ringing of the point ``point_E`` (in E, m; default the default tool's tip) after each stop of
        ``motion`` (a motion script) up to ``until_s`` s, found on a grid of ``grid_s`` s: a move is one whose
        point reaches ``min_speed`` m/s (the tail of a stop is none); ``params`` as the record's other fields."""
        t = np.arange(0.0, until_s, grid_s)
        state = motion.evaluate(t)
        w_B = (state.R_BE @ state.w_BE_E[..., None])[..., 0]
        r_B = state.R_BE @ np.asarray(point_E, dtype=float)
        v = state.v_BEo_B + np.cross(w_B, r_B)
        speed = np.linalg.norm(v, axis=1)
        stops, velocities = [], []
        peak, at = 0.0, 0
        for i, s in enumerate(speed):
            if s > peak:
                peak, at = s, i
            elif peak >= min_speed and s < 0.01 * peak:
                stops.append(t[i])
                velocities.append(v[at])
                peak = 0.0
            elif peak < min_speed:
                peak = s
        return cls(np.array(stops), np.array(velocities).reshape(-1, 3), **params)

    def force_B(self, t: np.ndarray, gravity_accel_B: np.ndarray) -> np.ndarray:
        """(N, 3) the swinging part's spring force on the tool at times ``t`` (N,) s, in B, N (gravity unused)."""
        t = np.asarray(t, dtype=float)
        w = 2 * math.pi * self.frequency_hz
        w_d = w * math.sqrt(1.0 - self.damping_ratio**2)
        force = np.zeros((len(t), 3))
        for stop, v in zip(self.stops_s, self.velocity_B, strict=True):
            tau = t - stop
            on = (tau >= 0) & (tau <= self.duration_s)
            if on.any():
                swing = np.exp(-self.damping_ratio * w * tau[on]) * np.sin(w_d * tau[on])
                force[on] += (self.mass * w * w / w_d) * swing[:, None] * v
        return force
