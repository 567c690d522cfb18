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
    """The observer and controller of one haptic port (module docstring).

    Args:
        max_damping: the most damping added, N·s/m.
        enabled: False: observe only.
    """

    def __init__(self, max_damping: float, enabled: bool = True):
        self.max_damping = float(max_damping)
        self.enabled = enabled
        self.energy_J = 0.0  # E: the energy the device has put into the hand up to now, J (≤ 0 while passive)
        self.damping = 0.0  # the damping added at the last tick, N·s/m
        self.active_ticks = 0  # ticks with damping added
        self._last: tuple[list[float], float] | None = None  # the force sent last (N) and for how long (s)

    def reset(self) -> None:
        """Start the account afresh (teleoperation re-engaged: the hand took the handle where it now is)."""
        self.energy_J, self._last = 0.0, None

    def apply(self, force_D: np.ndarray, v_D: np.ndarray | None, dt: float, add: bool = True) -> np.ndarray:
        """The force (3,) N to send instead of ``force_D`` for the next ``dt`` s, the handle moving at ``v_D``
        (3,) m/s now (None: the device reports no velocity: nothing observed, nothing added). ``add`` False:
        observe only (a command the gate holds at zero stays zero: damping is a force too).

        First the last tick is accounted with the velocity it ended at (the force sent then times the velocity
        now, as an independent check of the recording computes it); then the damping is chosen so that this
        tick, at the velocity now, leaves the energy at zero at most."""
        self.damping = 0.0
        if v_D is None or dt <= 0:
            self._last = None
            return force_D
        v = v_D.tolist()
        if self._last is not None:
            (fx, fy, fz), last_dt = self._last
            self.energy_J += (fx * v[0] + fy * v[1] + fz * v[2]) * last_dt
        f = force_D.tolist()
        speed2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        energy = self.energy_J + (f[0] * v[0] + f[1] * v[1] + f[2] * v[2]) * dt
        if add and self.enabled and energy > 0.0 and speed2 > MIN_SPEED * MIN_SPEED and math.isfinite(energy):
            self.damping = min(energy / (speed2 * dt), self.max_damping)
            self.active_ticks += 1
            force_D = force_D - self.damping * v_D
        self._last = (force_D.tolist(), dt)
        return force_D
