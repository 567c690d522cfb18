"""``inertia``: the tool's inertial wrench from the recorded motion.

Newton and Euler for the tool (mass m, centre of mass c = ``cog_S``, inertia
I about the centre of mass, axes of S), about the sensor origin, in S::

    F_i = −k m a_cm,    a_cm = a_E + α × (p + c) + ω × (ω × (p + c))
    τ_i = c × F_i − (I α + ω × I ω)

with a_E the acceleration of the flange origin (the recorded positions') and
p the sensor origin from the flange origin (in S), so a_E + α × p + ω × (ω × p)
is the sensor origin's acceleration. m is the mass of the tool's weight
(``|gravity_force_B| / g``) and c the base model's centre of mass, so the
parameters are ``k`` (``mass_scale``: 1 when the weight and the inertia are
the same mass; free, so an unsure time base cannot fake or hide the term,
since every inertial term scales as 1/time²), the six entries of I (kg·m²) and
p (m; it moves only the force, through α × p and ω × (ω × p), and the centre
of mass c is pinned by the weight's moment, so p is identifiable apart from c;
if the recorded positions are of another point on the flange, p is the sensor
origin from that point). ω, α (and a_E, when the recording has positions;
otherwise the translational term is left out and a note says so) come from
the recorded poses (``hapticlab.core.sensor_model.motion.motion_from_poses``).
"""

from __future__ import annotations

from typing import cast

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.frames import cross
from hapticlab.core.sensor_model import Effect, ModelState, Motion

MIN_RATE_HZ = 25.0
"""Below this sample rate the poses do not resolve a robot's accelerations."""


def _inertia_matrix(p: np.ndarray) -> np.ndarray:
    xx, yy, zz, xy, xz, yz = p
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


class Inertia(Effect):
    """Inertial wrench of the tool: ``mass_scale`` k, the inertia I_S (kg·m²) about the centre of mass, the
    sensor offset p (m)."""

    stage = "load"
    labels = ("mass_scale", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz", "px_m", "py_m", "pz_m")
    steps = (1e-3, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4)
    description = "tool inertial wrench from the motion"

    def check(self, motion: Motion) -> str | None:
        if not motion.has_time:
            return "needs a time base in seconds (t counts rows here)"
        if motion.rate_hz is not None and motion.rate_hz < MIN_RATE_HZ:
            return f"needs at least {MIN_RATE_HZ:g} samples/s to see accelerations (here {motion.rate_hz:.3g})"
        if np.abs(cast(np.ndarray, motion.w_E)).max() < 0.05:  # (has_time: the derivatives exist)
            return "the flange hardly turns (angular speed below 0.05 rad/s)"
        return None

    def notes(self, motion: Motion) -> list[str]:
        if motion.has_time and motion.a_B is None:
            return [
                "inertia: no flange positions in the recording, so only the rotational terms "
                "(α × c, ω × (ω × c), I α + ω × I ω) are modelled"
            ]
        return []

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        params = np.asarray(params, dtype=float)
        c = np.asarray(state.cog_S, dtype=float)
        key = ("inertia", state.R_SE.tobytes(), params.tobytes(), c.tobytes(), state.mass_kg)
        force_i, moment_i, euler = state.cached(key, lambda: self._wrench(state, params))
        return state.replace(force_S=state.force_S + force_i, torque_S=state.torque_S + moment_i - euler)

    @staticmethod
    def _wrench(state: ModelState, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The inertial wrench's terms ``(F_i, c × F_i, I α + ω × I ω)`` in S, N and N·m.

        The acceleration of the centre of mass and the Euler term are kept apart along the motion: a Jacobian's
        inertia columns move one of them at a time, its weight columns neither."""
        motion = state.motion
        c = state.cog_S
        r = c + params[7:10]  # the centre of mass from the flange origin, in S
        R_SE = state.R_SE.tobytes()

        def acceleration() -> np.ndarray:
            # (check() asked for a time base: the derivatives exist)
            w_S, alpha_S = state.motion_S("w_E"), state.motion_S("alpha_E")
            a_cm: np.ndarray = cross(alpha_S, r) + cross(w_S, cross(w_S, r))
            if motion.a_B is not None:
                a_cm = a_cm + state.motion_S("a_E")
            return a_cm

        def euler() -> np.ndarray:
            w_S, alpha_S = state.motion_S("w_E"), state.motion_S("alpha_E")
            inertia = _inertia_matrix(params[1:7])
            term: np.ndarray = alpha_S @ inertia.T + cross(w_S, w_S @ inertia.T)
            return term

        a_cm = state.cached(("inertia a_cm", R_SE, np.asarray(r, float).tobytes()), acceleration)
        force_i = -params[0] * state.mass_kg * a_cm
        return force_i, cross(c, force_i), state.cached(("inertia euler", R_SE, params[1:7].tobytes()), euler)

    def describe(self, params: np.ndarray) -> dict:
        return {
            "mass_scale": float(params[0]),
            "inertia_S": _inertia_matrix(params[1:7]).tolist(),
            "sensor_offset_S": [float(v) for v in params[7:10]],
        }

    def summary(self, params: np.ndarray) -> str:
        diag = ", ".join(f"{v:.2g}" for v in params[1:4])
        offset = ", ".join(f"{1e3 * v:.1f}" for v in params[7:10])
        return f"mass scale {params[0]:.3f}, inertia diag [{diag}] kg·m², sensor offset [{offset}] mm"

    def estimator_options(self, params: np.ndarray) -> dict:
        return {}


@hookimpl
def register_effects(register):
    """Register ``inertia``."""
    register("inertia", Inertia)
