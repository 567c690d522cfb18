"""``payload_change``: the tool's mass changes at one instant (a clip, a needle, a tool swap).

A mass Δm added at the point p (in S, from the sensor origin) at time t_c adds,
from t_c on, the weight Δm·g along gravity and its moment p × Δm·g. With W_S
the tool's weight in S (``R_SE R_EB gravity_force_B``) that is::

    F += s · W_S,    τ += d × W_S,    for t ≥ t_c

with ``s = Δm / m`` (``mass_ratio``; negative for a mass taken off) and
``d = s · p`` (``moment_S``, m): the centre of mass after the change is
``(cog_S + d) / (1 + s)``. Both enter linearly; the instant t_c does not (a
step of zero size has no instant), so before each candidate test the effect
puts t_c where the current residual's force best fits a step along the weight
(:meth:`PayloadChange.locate`, a scan over every row between the first and
last twentieth of the recording) and keeps it there: the instant is found,
not fitted, to within the rows either side of it. The scan sees every row,
the held-out folds' too, so the candidate test is a little optimistic for this
effect, and it is only looked for along a time base in seconds (static poses
may have been taken in any order). The added mass's own inertia and swing are
left out (quasi-static, as ``HangingMass`` in the simulator). See
``docs/discrepancy.md`` for how small a change shows and what it names on
clean recordings.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.frames import cross
from hapticlab.core.sensor_model import Effect, ModelState, Motion

EDGE = 0.05
"""Share of the rows at either end where no change is looked for (a step there is a bias or a weight)."""


class PayloadChange(Effect):
    """A step in the tool's mass (ratio to the tool's) and first moment (m) at a located instant."""

    stage = "load"
    description = "the tool's mass changing at one instant"
    labels = ("mass_ratio", "moment_S_x", "moment_S_y", "moment_S_z")
    steps = (1e-4, 1e-6, 1e-6, 1e-6)

    def __init__(self):
        self.t_change = 0.0
        self.mass_kg = float("nan")  # the tool's, from the last weight seen (for describe)

    def check(self, motion: Motion) -> str | None:
        if motion.time_base == "index":  # e.g. static poses, which may have been taken in any order
            return "needs a time base in seconds (t counts rows here: no history for a load to change along)"
        if len(motion) < 40 or np.ptp(motion.t) <= 0:
            return "the recording is too short to have a before and an after"
        self.t_change = float(np.median(motion.t))
        return None

    def locate(self, motion: Motion, residual: np.ndarray, weight_S: np.ndarray) -> None:
        """The instant (between two rows) where a step along the weight best explains the force residual.

        Each row's residual is projected on the weight there; the step's gain beside the weight itself (which
        the base fit scales already) is found for every instant at once from the running sums."""
        order = np.argsort(motion.t, kind="stable")
        t, r, u = motion.t[order], residual[order, :3], weight_S[order]
        a = np.einsum("ij,ij->i", r, u)  # each row's residual along the weight
        q = np.einsum("ij,ij->i", u, u)
        # the step from row c on, beside the weight itself (which the base fit already scales): the gain of
        # regressing r on [u, u·1(k ≥ c)] over regressing on u alone
        b, B = np.cumsum(a[::-1])[::-1], np.cumsum(q[::-1])[::-1]
        a_all, q_all = b[0], B[0]
        n = len(t)
        lo, hi = max(1, int(EDGE * n)), min(n - 1, int((1 - EDGE) * n))
        if hi <= lo:
            return
        bc, Bc = b[lo:hi], B[lo:hi]
        denominator = Bc - Bc**2 / q_all
        gain = np.divide(
            (bc - a_all * Bc / q_all) ** 2, denominator, out=np.zeros_like(denominator), where=denominator > 0
        )
        c = lo + int(np.argmax(gain))
        self.t_change = 0.5 * float(t[c - 1] + t[c])

    def apply(self, state: ModelState, params: np.ndarray) -> ModelState:
        after = (state.motion.t >= self.t_change)[:, None]
        weight_S = state.weight_S
        s, d = float(params[0]), np.asarray(params[1:4], float)
        self.mass_kg = state.mass_kg  # the tool's before the change, for describe (the last prediction's)
        return state.replace(
            force_S=state.force_S + after * (s * weight_S), torque_S=state.torque_S + after * cross(d, weight_S)
        )

    def describe(self, params: np.ndarray) -> dict:
        s, d = float(params[0]), np.asarray(params[1:4], float)
        out = {"t_change_s": self.t_change, "mass_ratio": s, "moment_S": d.tolist(), "added_mass_kg": s * self.mass_kg}
        out["point_S"] = (d / s).tolist() if abs(s) > 1e-6 else None
        return out

    def summary(self, params: np.ndarray) -> str:
        found = self.describe(params)
        point = found["point_S"]
        where = f" at [{', '.join(f'{1e3 * v:.0f}' for v in point)}] mm" if point is not None else ""
        return (
            f"{found['added_mass_kg'] * 1e3:+.0f} g ({100 * found['mass_ratio']:+.1f} % of the tool){where} "
            f"from {self.t_change:.3f} s"
        )


@hookimpl
def register_effects(register):
    """Register ``payload_change``."""
    register("payload_change", PayloadChange)
