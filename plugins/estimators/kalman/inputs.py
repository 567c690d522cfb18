"""What the ``kalman`` filter is given: the readings with the configured effects applied.

The calibration error undone (``gain_force_S``), the orientation at the sensor's own time (``time_lag_s``: a
late kinematics stream extrapolated from the motion's derivatives, a late sensor stream interpolated from
the poses already seen) and the tool's inertial force (``inertia``), in S.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import aligner_kernel
from hapticlab.core.aligner import orientation_at, position_at
from hapticlab.core.frames import GRAVITY_M_S2, matrix_from_quat_wxyz, quat_from_rotvec, quat_wxyz_from_matrix
from hapticlab.core.types import AlignedSamples
from hapticlab.plugins.estimators.kalman import derivatives_kernel
from hapticlab.plugins.estimators.kalman.base import KalmanBase
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_FORCE_SEEN, ADAPT_TORQUE_SEEN

LAG_HISTORY_MARGIN_NS = 50_000_000
"""Poses kept beyond the lag itself (50 ms), for the next block's interpolation."""
NO_POSITIONS = np.zeros((0, 3))
"""What the compiled cascade is given for a stream without positions."""


class ModelInputs(KalmanBase):
    """The model's inputs per block (a part of :class:`KalmanEstimator`)."""

    def _to_S(self, R_EB: np.ndarray) -> np.ndarray:
        """(m, 3, 3) R_SB = R_SE R_EB: B's vectors into S through the mount (identity by default)."""
        if not (self.mount_rotation or self.mount_configured):
            return R_EB
        return self.R_SE @ R_EB

    def _prepare(
        self, block: AlignedSamples, usable: bool = True, motion: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The block's readings with the configured effects applied.

        Returns (force_S, torque_S, R_EB, inertial_force_S or None, usable): the readings
        through the inverse calibration error (gain_crosstalk), the orientation at the
        sensor's time (time_lag), the tool's inertial force (inertia) in S, N, and the
        samples that may update the filter (block.usable, less the first |τ| seconds of a
        late sensor stream, whose poses are not known). When ``usable`` is False (the
        compiled cascade tests the block's own flags itself) the last is None, or for a late
        sensor stream the (m,) mask of the samples whose poses are known. With ``motion`` (inertia on)
        the fourth is the motion the inertial force comes from, (m, 9) [ω_E rad/s, α_E rad/s², a_B
        m/s²], for the compiled cascade to compute it sample by sample.
        """
        force_S, torque_S, R_EB = block.force_S, block.torque_S, block.R_EB
        mask = block.usable if usable else None
        quat_BE, p_BoEo_B = block.quat_BE, block.p_BoEo_B
        if self.gain_inverse_force is not None:
            force_S = force_S @ self.gain_inverse_force.T
        if self.gain_inverse_torque is not None:
            torque_S = torque_S @ self.gain_inverse_torque.T
        if self.time_lag_s < 0:
            R_EB, quat_BE, p_BoEo_B, known = self._past_poses(block)
            mask = known if mask is None else mask & known
        if self.derivatives is None:
            return force_S, torque_S, R_EB, None, mask
        w_E, alpha_E, a_B = self.derivatives.update(block.t_ns, quat_BE, p_BoEo_B, R_EB=R_EB)
        if self.time_lag_s > 0:
            # the pose at the sensor's time t is stamped t + τ, not yet here: extrapolate,
            # R_BE(t + τ) = R_BE(t) Exp(ω τ + ½ α τ²)
            tau = self.time_lag_s
            step = matrix_from_quat_wxyz(quat_from_rotvec(w_E * tau + 0.5 * alpha_E * tau * tau))
            R_EB = step.transpose(0, 2, 1) @ R_EB
            w_E = w_E + alpha_E * tau
            # (a_B is not shifted: a second-order term of a second-order term)
        if motion and self.inertia:
            return force_S, torque_S, R_EB, np.concatenate([w_E, alpha_E, a_B], axis=1), mask
        if not self.inertia or not (self._adapt[ADAPT_FORCE_SEEN] or self._mass_known):
            # the mass comes from the identified weight: until the force stage has settled it may be
            # far off, and subtracting a wrong inertial force would feed back into the weight
            return force_S, torque_S, R_EB, None, mask
        return force_S, torque_S, R_EB, self._inertial_force(R_EB, w_E, alpha_E, a_B), mask

    def _past_poses(self, block: AlignedSamples) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
        """A late sensor stream (τ < 0): the poses at t + τ, interpolated from the poses already seen.

        Returns (R_EB (m, 3, 3), quat_BE (m, 4), p_BoEo_B (m, 3) or None, known (m,) bool:
        False where t + τ precedes every pose seen).
        """
        t = np.asarray(block.t_ns, dtype=np.int64)
        q = block.quat_BE if block.quat_BE is not None else quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
        hist_t = np.concatenate([self._lag_t, t])
        hist_q = np.concatenate([self._lag_q, q])
        has_p = block.p_BoEo_B is not None and self._lag_p is not None
        hist_p = np.concatenate([self._lag_p, block.p_BoEo_B]) if has_p else None
        target = t + round(self.time_lag_s * 1e9)
        known = target >= hist_t[0]
        if self.kernel == "numba":  # the live aligner's compiled interpolation (to ~1e-12 of the numpy one)
            m = len(t)
            quat_BE, R_EB, p_BoEo_B = np.empty((m, 4)), np.empty((m, 3, 3)), np.empty((m, 3)) if has_p else None
            aligner_kernel.align_block(
                target,
                hist_t,
                np.ascontiguousarray(hist_q, float),
                np.ascontiguousarray(hist_p, float) if has_p else NO_POSITIONS,
                0,
                quat_BE,
                R_EB,
                p_BoEo_B if p_BoEo_B is not None else NO_POSITIONS,
                np.empty(m, dtype=np.bool_),
            )
        else:
            quat_BE, _ = orientation_at(target, hist_t, hist_q, 0)
            p_BoEo_B = position_at(target, hist_t, hist_p, 0) if hist_p is not None else None
            R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
        keep = hist_t >= target[-1] - LAG_HISTORY_MARGIN_NS  # what the next block's targets may need
        keep[-2:] = True
        self._lag_t, self._lag_q = hist_t[keep], hist_q[keep]
        self._lag_p = hist_p[keep] if hist_p is not None else None
        return R_EB, quat_BE, p_BoEo_B, known

    def _inertial_force(self, R_EB: np.ndarray, w_E: np.ndarray, alpha_E: np.ndarray, a_B: np.ndarray) -> np.ndarray:
        """(m, 3) the tool's inertial force in S, −m (a + α × c + ω × (ω × c)), N.

        m = |gravity_force_B| / g and c = cog_S are the current estimates, used once the
        force stage has settled (converged; at the pose, identified as well: before that no
        inertial force is subtracted, a wrong weight would feed back through m); c once the
        torque stage has settled (until then the centre of mass is taken at the sensor origin).
        a is the flange's acceleration (the sensor is taken at the flange
        origin); ω, α in S through the mount.
        """
        mass = float(np.linalg.norm(self.force.x[:3])) / GRAVITY_M_S2
        cog_S = self.torque.x[:3] if (self._adapt[ADAPT_TORQUE_SEEN] or self._cog_known) else np.zeros(3)
        R_SE = self.R_SE
        if self.kernel == "numba":
            out = np.empty((len(R_EB), 3))
            derivatives_kernel.inertial_force(
                R_SE,
                np.ascontiguousarray(self._to_S(R_EB), float),
                np.ascontiguousarray(w_E, float),
                np.ascontiguousarray(alpha_E, float),
                np.ascontiguousarray(a_B, float),
                mass,
                np.ascontiguousarray(cog_S, float),
                out,
            )
            return out
        w_S, alpha_S = w_E @ R_SE.T, alpha_E @ R_SE.T
        a_S = np.einsum("kij,kj->ki", self._to_S(R_EB), a_B)
        a_cm_S = a_S + np.cross(alpha_S, cog_S) + np.cross(w_S, np.cross(w_S, cog_S))
        return -mass * a_cm_S
