"""The haptic port's passivity observer and controller: force feedback that cannot put energy into the hand.

Bilateral teleoperation goes unstable with a stiff contact, a delay or too little damping: the loop hand →
master → robot → tissue → force → hand then *creates* energy, and the handle shakes in the trainee's hand.
The time-domain passivity approach (Hannaford & Ryu 2002, "Time-domain passivity control of haptic
interfaces"; Ryu, Kwon & Hannaford 2004 for the delayed case) watches the energy at the port and dissipates
what it would create, whatever caused it:

* **observer**: the energy the device has put into the hand, ``E(n) = Σ_k F_D(k) · v_D(k) Δt`` (J; F the force
  on the handle, N, v the handle's velocity, m/s, both in D). A passive port keeps ``E ≤ 0``: it gives back
  at most what the hand put in;
* **controller**: when this tick's force would make ``E`` positive, it adds the least damping that keeps it at
  zero, ``α = E / (|v|² Δt)`` (N·s/m), capped at ``max_damping`` (what the device renders stably), and sends
  ``F − α v``.

The observer runs with the controller off too ("off": the energy is recorded, nothing added), so a recording
shows how active a setting is.
"""

from __future__ import annotations

import math

import numpy as np

MIN_SPEED = 1e-4
"""Below this handle speed (m/s) no damping is added: α would be a division by almost nothing, and a still
handle takes no energy from the port."""


class PassivityController:
    """The observer and controller of one haptic port (module docstring), once a device period:
    :meth:`observe` the handle's velocity, give the governor :meth:`damp` as its ``port``, :meth:`hold` what it
    sent.

    Args:
        max_damping: the most damping added, N·s/m. A damping rendered from a velocity one device period old is
            stable while ``max_damping · T / m < 1`` (m the handle's and hand's mass, T the period): 350 N·s/m for
            the simulated master at 1 kHz.
        enabled: False: observe only.
    """

    def __init__(self, max_damping: float, enabled: bool = True):
        self.max_damping = float(max_damping)
        self.enabled = enabled
        self.energy_J = 0.0  # E: the energy the device has put into the hand up to now, J (≤ 0 while passive)
        self.damping = 0.0  # the damping added at the last tick, N·s/m
        self.active_ticks = 0  # ticks with damping added
        self.capped_ticks = 0  # ...of which at max_damping
        self._held = [0.0, 0.0, 0.0]  # the force sent last, N: held since
        self._v: list[float] | None = None  # the handle's velocity now, m/s (None: unknown)
        self._dt = 0.0  # the last tick's length, s: what this one's is taken to be

    def reset(self) -> None:
        """Start the account afresh (teleoperation re-engaged: the hand took the handle where it now is)."""
        self.energy_J = 0.0

    def observe(self, v_D: np.ndarray | None, dt: float) -> None:
        """The handle moves at ``v_D`` (3,) m/s now, ``dt`` s after the last force was sent: that force, held
        over ``dt``, is accounted with this velocity, as an independent check of the recording does (None or
        a non-finite velocity: unknown, nothing accounted, nothing added this tick)."""
        self.damping, self._dt = 0.0, dt
        v = None if v_D is None else v_D.tolist()
        if v is None or not math.isfinite(v[0] + v[1] + v[2]):
            self._v = None
            return
        self._v = v
        f = self._held
        self.energy_J += (f[0] * v[0] + f[1] * v[1] + f[2] * v[2]) * dt

    def damp(self, force_D: list[float]) -> list[float]:
        """``force_D`` (N, in D) with the least damping that keeps E at zero at most over a tick as long as the
        last, at the velocity now, capped at ``max_damping`` (the governor then clamps and rate-limits it)."""
        v, f, dt = self._v, force_D, self._dt
        if v is None or not self.enabled or dt <= 0:
            return force_D
        speed2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        energy = self.energy_J + (f[0] * v[0] + f[1] * v[1] + f[2] * v[2]) * dt
        if energy <= 0.0 or speed2 <= MIN_SPEED * MIN_SPEED:
            return force_D
        self.damping = min(energy / (speed2 * dt), self.max_damping)
        self.active_ticks += 1
        self.capped_ticks += self.damping == self.max_damping
        return [f[0] - self.damping * v[0], f[1] - self.damping * v[1], f[2] - self.damping * v[2]]

    def hold(self, force_D: np.ndarray) -> None:
        """The force the device was sent, N in D: held until the next tick."""
        self._held = force_D.tolist()
