"""``sim``: a simulated desktop master with a simulated hand on its handle, in process.

The handle has mass and a little viscous friction, the force commanded acts on it, and a hand holds it:
an impedance (mass, damping, stiffness) pulling the handle toward where the trainee means it to be (the
*intent*: rest, then press down into the tissue, hold, release; or search for an inclusion, or trace a line:
``sim_hand.py``). So the loop hand → master → robot → tissue →
force → hand is closed: a force that pushes back moves the handle, as it moves a real hand, and an unstable
setting (a stiff contact, a delay, too little damping) shows as the handle oscillating and the port putting
energy into the hand (``sessions.live.passivity``).

Per axis of D, with x the handle's position, x_i the intent's (both m)::

    (handle_mass + hand_mass) ẍ = F_device − handle_damping ẋ + hand_stiffness (x_i − x) + hand_damping (ẋ_i − ẋ)

integrated by semi-implicit Euler in ``SUBSTEP_S`` steps, each command holding from its stamp to the next.

Ranges (the defaults in brackets), as the literature on stylus and finger-tip grips reports them:

* hand holding a stylus: effective mass 0.05–0.5 kg [0.2], damping 2–20 N·s/m [8], stiffness 100–1000 N/m
  [400] from a relaxed to a stiff grip (Hajian & Howe 1997, finger tip; Fu & Çavuşoğlu 2012, arm and hand on a
  stylus device; Kuchenbecker et al. 2003, wrist);
* desktop device (a Phantom-class or Inverse3-class master, at the handle): mass 0.05–0.3 kg [0.15], viscous
  friction 0.1–1 N·s/m [0.5].
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.host.options import choice, integer, number
from hapticlab.core.types import DeviceState, HapticCommand
from hapticlab.plugins.haptics.sim_hand import SCRIPTS, hand_script

SUBSTEP_S = 0.00025
"""Integration step, s: four a 1 kHz command, and ω·h ≤ 0.02 for the stiffest hand of the ranges below (1000 N/m
on 0.35 kg with the handle: ω = 53 rad/s), where semi-implicit Euler is stable for ω·h < 2."""
HOME_QUAT_DH = np.array([1.0, 0.0, 0.0, 0.0])


class SimMaster:
    """A simulated master and hand (HapticOutput); module docstring for the model and its ranges.

    Args:
        rate_hz: the device's command rate, Hz.
        handle_mass, handle_damping: the device at its handle, kg and N·s/m.
        hand_mass, hand_damping, hand_stiffness: the hand's impedance, kg, N·s/m, N/m.
        press_at: when the intent starts pressing, s after the first command.
        depth: how far down (D's −z) the intent presses, m.
        ramp: how long the intent takes to go down (and to come back up), s (a raised cosine).
        hold: how long it stays down, s (each probe's, ``palpate``; the slide's, ``trace``).
        script: what the hand does (``sim_hand.SCRIPTS``): ``press`` (one indentation), ``palpate`` (search
            for the firmest spot and mark it), ``trace`` (slide along a line while pressing).
        span: the row of probes' (``palpate``) or the line's (``trace``) length along D's x, m.
        probes: how many presses ``palpate`` makes over ``span``.
        mark_button: the bit of the buttons ``palpate`` presses to mark the spot it chose.
    """

    def __init__(
        self,
        rate_hz: float = 1000.0,
        handle_mass: float = 0.15,
        handle_damping: float = 0.5,
        hand_mass: float = 0.2,
        hand_damping: float = 8.0,
        hand_stiffness: float = 400.0,
        press_at: float = 12.0,
        depth: float = 0.03,
        ramp: float = 1.0,
        hold: float = 3.0,
        script: str = "press",
        span: float = 0.06,
        probes: int = 5,
        mark_button: int = 1,
    ):
        self.rate_hz = number("rate_hz", rate_hz, above=0, maximum=10_000, hint=" Hz")
        self.mass = number("handle_mass", handle_mass, above=0, maximum=10, hint=" kg") + number(
            "hand_mass", hand_mass, minimum=0, maximum=10, hint=" kg"
        )
        self.handle_damping = number("handle_damping", handle_damping, minimum=0, maximum=1e3, hint=" N·s/m")
        self.hand_damping = number("hand_damping", hand_damping, minimum=0, maximum=1e3, hint=" N·s/m")
        self.hand_stiffness = number("hand_stiffness", hand_stiffness, minimum=0, maximum=1e5, hint=" N/m")
        self.press_at = number("press_at", press_at, minimum=0, hint=" s")
        self.depth = number("depth", depth, minimum=0, maximum=0.5, hint=" m")
        self.ramp = number("ramp", ramp, above=0, maximum=60, hint=" s")
        self.hold = number("hold", hold, minimum=0, hint=" s")
        self.script = hand_script(
            choice("script", script, SCRIPTS),
            press_at=self.press_at,
            depth=self.depth,
            ramp=self.ramp,
            hold=self.hold,
            span=number("span", span, minimum=0, maximum=1, hint=" m"),
            probes=integer("probes", probes, minimum=1, maximum=50),
            mark_button=integer("mark_button", mark_button, minimum=-1, maximum=31),
        )
        self.buttons = 0
        self.p = np.zeros(3)  # the handle's position in D, m
        self.v = np.zeros(3)  # its velocity, m/s
        self.force = np.zeros(3)  # the command in force, N
        self.t0_ns: int | None = None
        self.t_ns = 0

    def intent(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Where the hand means the handle to be at ``t`` s after the first command, m in D, and how fast, m/s."""
        p, v, self.buttons = self.script.intent(t, self.force)
        return p, v

    def open(self) -> None:
        """Nothing to open: the handle rests at the origin of D."""

    def send(self, command: HapticCommand) -> None:
        """The handle moves under the previous command until ``command.t_ns``; this one holds from then on."""
        if self.t0_ns is None:
            self.t0_ns = self.t_ns = command.t_ns
        steps = max(0, round((command.t_ns - self.t_ns) * 1e-9 / SUBSTEP_S))
        dt = (command.t_ns - self.t_ns) * 1e-9 / steps if steps else 0.0
        t = (self.t_ns - self.t0_ns) * 1e-9
        for _ in range(steps):
            t += dt
            p_i, v_i = self.intent(t)
            hand = self.hand_stiffness * (p_i - self.p) + self.hand_damping * (v_i - self.v)
            self.v = self.v + dt * (self.force - self.handle_damping * self.v + hand) / self.mass
            self.p = self.p + dt * self.v
        self.t_ns = command.t_ns
        self.force = np.array(command.force_D, dtype=float)

    def state(self) -> DeviceState | None:
        """The handle's pose and velocity (CRTK ``measured_cp``, ``measured_cv``) at the newest command."""
        return DeviceState(self.t_ns, HOME_QUAT_DH, self.p.copy(), self.buttons, self.v.copy())

    def close(self) -> None:
        """Nothing to close."""


@hookimpl
def register_haptic_outputs(register):
    """Register the simulated master and hand as ``sim``."""
    register("sim", SimMaster)
