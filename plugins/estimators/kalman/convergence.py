"""What the ``kalman`` estimator knows: when its stages count as converged, what the motion has identified of
the tool, and the parameters it reports.

The rules of the ``convergence`` option ("pose", "identified", "covariance", "step"), the parameters'
std the haptic gate reads, the ``identified`` / ``not_identifiable`` events (``identified.py`` holds
the math), ``params()`` and ``cov_diag()``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hapticlab.core.estimation.model import named_params
from hapticlab.core.frames import rotvec_from_matrix
from hapticlab.core.types import Event
from hapticlab.plugins.estimators.kalman import identified, identified_kernel, torque_bias
from hapticlab.plugins.estimators.kalman.base import KalmanBase
from hapticlab.plugins.estimators.kalman.noise import AUTO_BOUND_FRACTION
from hapticlab.plugins.estimators.kalman.state_layout import (
    ADAPT_CAP_F,
    ADAPT_CAP_T,
    ADAPT_FORCE_SEEN,
    ADAPT_PRED_F,
    ADAPT_TW,
)
from hapticlab.plugins.estimators.kalman.tilt_walk_kernel import TW_PAIRS, TW_Q

STEP_EPSILON = 1e-3
"""``convergence = "step"``: the paper's threshold on ‖Δx‖ (mixed units, as in Algorithm 1)."""
IDENTIFICATION_EVENTS = ("identified", "not_identifiable")
"""The kinds of the events that say what the motion has identified of the tool (``convergence`` "pose" or
"identified")."""
CONVERGED_FORCE_STD = 0.02
"""Default convergence bound with a configured noise, N (one sixth of the Gamma-class 0.12 N)."""
CONVERGED_TORQUE_STD = 0.002
"""Default convergence bound with a configured noise, N·m."""


class Convergence(KalmanBase):
    """Convergence and identification (a part of :class:`KalmanEstimator`)."""

    def _bounds(self) -> tuple[float, float]:
        """(force bound N, torque bound N·m) on the parameters' std for convergence."""
        f, t = self.converged_force_std_option, self.converged_torque_std_option
        if f is None:
            f = (
                AUTO_BOUND_FRACTION * float(np.sqrt(self.force.r.mean()))
                if self.noise_auto_force
                else CONVERGED_FORCE_STD
            )
            f = min(f, self._adapt[ADAPT_CAP_F])  # an auto bound never grows past its value once settled
        if t is None:
            t = (
                AUTO_BOUND_FRACTION * float(np.sqrt(self.torque.r.mean()))
                if self.noise_auto_torque
                else CONVERGED_TORQUE_STD
            )
            t = min(t, self._adapt[ADAPT_CAP_T])
        return f, t

    def _force_converged(self, run_f, x_before, accepted, A_f) -> tuple[np.ndarray, np.ndarray]:
        """(m,) the force stage's flag after each sample, and (m,) whether it has settled there (the flag;
        at the pose, the identified rule's test as well: the noise estimate and the inertial force wait for
        it)."""
        if self.convergence == "step":
            conv = self._step_converged(run_f.X[:, :6], x_before, accepted, self.converged_force)
            return conv, conv
        bound2 = self._bounds()[0] ** 2
        if self.identifies:  # gravity from the motion's information; the force at this pose
            predicted = self._adapt[ADAPT_PRED_F : ADAPT_PRED_F + 3]
            predicted[:] = identified.predicted_var(self.force.P, A_f[-1])
            known_here = np.array([predicted.max() < bound2])
            settled = (self._identified_var("force", A_f, accepted) < bound2) & known_here
            conv = known_here if self.convergence == "pose" else settled
        else:
            conv = settled = run_f.D[:, :6].max(axis=1) < bound2
        if self.mount_rotation:  # the force a mount error can cause: std(θ)·|gravity_force_B|
            n = self.force.n
            weight2 = (run_f.X[:, :3] ** 2).sum(axis=1)
            mount_known = run_f.D[:, n - 3 : n].max(axis=1) * weight2 < bound2
            conv, settled = conv & mount_known, settled & mount_known
        return conv, settled

    def _torque_converged(self, run_t, X_f, x_before, accepted, A_t) -> tuple[np.ndarray, np.ndarray]:
        """(m,) the torque stage's flag after each sample, and (m,) whether it has settled there (as for the
        force stage: at the pose, the centre of gravity identified as well)."""
        if self.convergence == "step":
            conv = self._step_converged(run_t.X[:, :6], x_before, accepted, self.converged_torque)
            return conv, conv
        bound2 = self._bounds()[1] ** 2
        weight2 = (X_f[:, :3] ** 2).sum(axis=1)  # |gravity_force_B|², N²
        if self.identifies:
            identified_here = self._identified_var("torque", A_t, accepted) * weight2 < bound2  # (Λ kept)
            known_here = np.array([identified.predicted_var(self.torque.P, A_t[-1]).max() < bound2])
            settled = identified_here & known_here
            return (known_here, settled) if self.convergence == "pose" else (settled, settled)
        conv = (run_t.D[:, :3].max(axis=1) * weight2 < bound2) & (run_t.D[:, 3:6].max(axis=1) < bound2)
        return conv, conv

    def _identified_var(self, stage: str, A: np.ndarray, accepted: np.ndarray) -> np.ndarray:
        """(1,) the largest variance of the stage's constant (gravity_force_B, N², or cog_S, m²) after a
        sample (the numpy reference runs this rule one sample at a time), from the information its
        accepted samples carry with the bias held constant (``plugins.estimators.kalman.identified``); Λ is re-seeded
        from P whenever the estimator re-opens a parameter."""
        if accepted[0]:
            r = (self.force if stage == "force" else self.torque).r
            self._information[stage] = identified.add_information(self._information[stage], A[0], r)
        return identified.constant_var(self._information[stage]).max(keepdims=True)

    def _unidentified_now(self, stage: str) -> tuple[list[float], tuple[int, ...]]:
        """The stage's constant (gravity_force_B, N; cog_S, m): std per axis, and the axes not identified
        (plain floats: params() and the events run it every block)."""
        # a variance < 0 or NaN is the rounding of a singular information: nothing identified
        std = [math.sqrt(v) if v >= 0 else math.inf for v in self._constant_var(stage)]
        return std, identified.unidentified_axes(std, self._prior_constant(stage))

    def _prior_constant(self, stage: str) -> float:
        """The prior std of the stage's constant: gravity_force_B's (N) or cog_S's (m)."""
        return float((self.prior_f if stage == "force" else self.prior_t)[0])

    def _watch_identified(self, t_ns: int) -> None:
        """An event when what the motion identifies of a constant changes: ``not_identifiable`` when it has
        identified some of its axes but not all (which, and how to move), ``identified`` once it has all;
        only while every axis is clearly one or the other (``plugins.estimators.kalman.identified.decided``: as a motion
        starts, its axes pass from one to the other within milliseconds). All three unidentified (a still tool, the
        start, a re-opened bias) is no news."""
        for stage, name, frame in (("force", "gravity_force_B", "B"), ("torque", "cog_S", "S")):
            std, axes = self._unidentified_now(stage)
            if axes == self._unidentified[name] or not identified.decided(std, self._prior_constant(stage)):
                continue
            self._unidentified[name] = axes
            unit = "N" if stage == "force" else "m"
            data: dict[str, Any] = {"parameter": name, "axes": ["xyz"[i] for i in axes], "std": std}
            if not axes:
                self.events.append(
                    Event(
                        t_ns,
                        "identified",
                        f"{name} identified by the motion on every axis "
                        f"(std {', '.join(f'{v:.2g}' for v in std)} {unit})",
                        data,
                    )
                )
            elif len(axes) < 3:
                self.events.append(
                    Event(
                        t_ns,
                        "not_identifiable",
                        (
                            f"{name} along {frame}'s {', '.join(data['axes'])} not identifiable from the motion so far "
                            f"(std {', '.join(f'{std[i]:.2g}' for i in axes)} {unit}): turn the tool about another axis"
                        ),
                        data,
                    )
                )

    @staticmethod
    def _step_converged(X, x_before, accepted, flag) -> np.ndarray:
        """The paper's criterion: ‖Δx‖ < 1e-3 at each accepted sample, held between them."""
        steps = np.linalg.norm(np.diff(np.vstack([x_before[None, :], X]), axis=0), axis=1)
        out = np.empty(len(X), dtype=bool)
        for k in range(len(X)):
            if accepted[k]:
                flag = bool(steps[k] < STEP_EPSILON)
            out[k] = flag
        return out

    def _constant_var(self, stage: str) -> tuple[float, float, float]:
        """How well the motion so far identifies the stage's constant, variance per axis
        (``plugins.estimators.kalman.identified.constant_var``; compiled, ``identified_kernel.constant_var3``, on the
        compiled path)."""
        if self.method == "numba" or self._cascade:
            return identified_kernel.constant_var3(self._information[stage], self._L6)
        return tuple(identified.constant_var(self._information[stage]).tolist())

    def force_parameter_std(self) -> np.ndarray:
        """(6,) standard deviation of [gravity_force_B, bias_force_S], N: sqrt of diag P_force.

        With ``convergence`` "pose" or "identified" what the identified rule judges: gravity's std as the motion
        identifies it, and in the bias's place the non-contact force's std per axis at the last sample's pose
        (the bias as known where the robot is), so the haptic gate's "parameters known" agrees with that rule's
        flag; inf until the force stage has settled (the tool identified to the estimator's own bound, which
        may be tighter than the gate's ``ready_force_std``): under "pose" the flag rises before, the haptic
        force waits for both."""
        predicted = self._adapt[ADAPT_PRED_F : ADAPT_PRED_F + 3]
        if self.identifies and not np.isnan(predicted).any():
            if not self._adapt[ADAPT_FORCE_SEEN]:  # not yet identified to the estimator's own bound: inf
                return np.full(6, math.inf)
            return np.sqrt(np.concatenate([self._constant_var("force"), predicted]))
        return np.sqrt(np.diag(self.force.P)[:6])

    def torque_parameter_std(self) -> np.ndarray:
        """(6,) standard deviation of the torque stage's state [cog_S (m), its bias about the measured force
        (N·m): ``torque_bias``]: sqrt of diag P_torque, what the covariance flag bounds (the compensated torque is
        τ − cog_S × the force model − that bias)."""
        return np.sqrt(np.diag(self.torque.P)[:6])

    def params(self) -> dict[str, list[float]]:
        """Identified parameters with physical names (SI units); with bias_rate also the bias rates; with
        ``convergence`` "pose" or "identified" the std per axis of gravity_force_B (N) and cog_S (m) as the motion so
        far identifies them, and NaN for an axis it has not identified at all (``plugins.estimators.kalman.identified.
        unidentified_axes``: a still tool leaves all three, a turn about B's vertical alone gravity's vertical
        component; the ``not_identifiable`` event names them); with auto noise the noise estimates."""
        x_t = torque_bias.physical(self.torque.x, *self._force_biases())
        out = named_params(self.force.x[:6], x_t[:6])
        if self.mount_rotation or self.mount_configured:
            out["mount_rotation_SE"] = rotvec_from_matrix(self.R_SE).tolist()  # rad
        if self.identifies:  # how well the motion so far has identified the constants
            for stage, name in (("force", "gravity_force_B"), ("torque", "cog_S")):
                std, axes = self._unidentified_now(stage)
                out[f"{name}_std"] = std  # N, m
                for i in axes:  # not identifiable from the motion so far: no number
                    out[name][i] = math.nan
        if self.noise_auto:
            out["noise_force_S"] = np.sqrt(self.force.r).tolist()  # N
            out["noise_torque_S"] = np.sqrt(self.torque.r).tolist()  # N·m
        if self.tilt_walk_auto:  # the tilt walk learnt so far, N/√rad, and from how many pairs of windows
            out["bias_force_tilt_rw"] = [math.sqrt(self._adapt[ADAPT_TW + TW_Q])]
            out["tilt_walk_pairs"] = [float(self._adapt[ADAPT_TW + TW_PAIRS])]
        if self.bias_rate:
            out["bias_force_rate_S"] = self.force.x[6:9].tolist()  # N/s
            out["bias_torque_rate_S"] = x_t[6:9].tolist()  # N·m/s
        return out

    def cov_diag(self) -> list[float]:
        """Diagonal of P for the force stage then the torque stage (12 values; 18 with bias_rate;
        3 more, the mount's θ at the end of the force stage's, with mount_rotation)."""
        return np.concatenate([np.diag(self.force.P), np.diag(self.torque.P)]).tolist()
