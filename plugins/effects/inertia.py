"""``inertia``: the tool's inertial wrench from the recorded motion.

Newton and Euler for the tool (mass m, centre of mass c = ``cog_S``, inertia
I about the centre of mass, axes of S), about the sensor origin, in S::

    F_i = −k m a_cm,    a_cm = a_S + α × c + ω × (ω × c)
    τ_i = c × F_i − (I α + ω × I ω)

m is the mass of the tool's weight (``|gravity_force_B| / g``) and c the base
model's centre of mass, so the parameters are ``k`` (``mass_scale``: 1 when
the weight and the inertia are the same mass; free, so an unsure time base
cannot fake or hide the term, since every inertial term scales as 1/time²)
and the six entries of I (kg·m²). ω, α (and a_S, the flange's linear
acceleration, when the recording has positions; otherwise the translational
term is left out and a note says so) come from the recorded poses
(``hapticlab.core.effects.motion_from_poses``). The sensor origin is taken at
the flange origin for a_S (a few centimetres of offset change a_cm by α × p).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.effects import Effect, ModelState, Motion
from hapticlab.core.frames import cross

MIN_RATE_HZ = 25.0
"""Below this sample rate the poses do not resolve a robot's accelerations."""


def _inertia_matrix(p: np.ndarray) -> np.ndarray:
    xx, yy, zz, xy, xz, yz = p
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


class Inertia(Effect):
    """Inertial wrench of the tool: ``mass_scale`` k and the inertia I_S (kg·m²) about the centre of mass."""

    stage = "load"
    labels = ("mass_scale", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
    steps = (1e-3, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6)
    description = "tool inertial wrench from the motion"

    def check(self, motion: Motion) -> str | None:
        if not motion.has_time:
            return "needs a time base in seconds (t counts rows here)"
        if motion.rate_hz is not None and motion.rate_hz < MIN_RATE_HZ:
            return f"needs at least {MIN_RATE_HZ:g} samples/s to see accelerations (here {motion.rate_hz:.3g})"
        if np.abs(motion.w_E).max() < 0.05:
            return "the flange hardly turns (angular speed below 0.05 rad/s)"
        return None

    def notes(self, motion: Motion) -> list[str]:
        if motion.has_time and motion.a_B is None:
            return ["inertia: no flange positions in the recording, so only the rotational terms "
                    "(α × c, ω × (ω × c), I α + ω × I ω) are modelled"]
        return []

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        motion = state.motion
        c = state.cog_S
        w_S = state.to_S(motion.w_E)
        alpha_S = state.to_S(motion.alpha_E)
        a_cm = cross(alpha_S, c) + cross(w_S, cross(w_S, c))
        if motion.a_B is not None:
            a_cm = a_cm + state.to_S(np.einsum("nij,nj->ni", motion.R_EB, motion.a_B))
        force_i = -params[0] * state.mass_kg * a_cm
        inertia = _inertia_matrix(params[1:])
        euler = alpha_S @ inertia.T + cross(w_S, w_S @ inertia.T)
        return state.replace(force_S=state.force_S + force_i,
                             torque_S=state.torque_S + cross(c, force_i) - euler)

    def describe(self, params: np.ndarray) -> dict:
        return {"mass_scale": float(params[0]), "inertia_S": _inertia_matrix(params[1:]).tolist()}

    def summary(self, params: np.ndarray) -> str:
        diag = ", ".join(f"{v:.2g}" for v in params[1:4])
        return f"mass scale {params[0]:.3f}, inertia diag [{diag}] kg·m²"

    def estimator_options(self, params: np.ndarray) -> dict:
        return {}


@hookimpl
def register_effects(register):
    """Register ``inertia``."""
    register("inertia", Inertia)
