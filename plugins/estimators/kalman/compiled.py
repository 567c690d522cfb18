"""The ``kalman`` estimator's compiled path: a block through the whole cascade in one call.

``_filter_block`` in ``estimator.py`` is the numpy reference, one stage after the other; this part hands
the block, both stages' state and the cascade's state array (``state_layout.py``) to
``cascade_kernel.kalman_cascade`` and reads back what it wrote. The default model takes this path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.plugins.estimators.kalman import cascade_kernel
from hapticlab.plugins.estimators.kalman.base import KalmanBase
from hapticlab.plugins.estimators.kalman.inputs import NO_POSITIONS
from hapticlab.plugins.estimators.kalman.stage import StageRun
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_AUTO_F, ADAPT_AUTO_T, ADAPT_REOPEN_ROW

if TYPE_CHECKING:
    from hapticlab.plugins.estimators.kalman.mount_stage import MountStage

NO_RATE = np.zeros(3)
"""What the compiled cascade is given for the bias rates' random walk without bias-rate states."""
NO_MOTION = np.zeros((0, 9))
"""What the compiled cascade is given when it does not compute the inertial force itself."""


class CompiledPath(KalmanBase):
    """The block through the compiled cascade (a part of :class:`KalmanEstimator`)."""

    def _filter_compiled(self, block: AlignedSamples, inertia_per_sample: bool = False) -> Estimates:
        """``_filter_block`` in one compiled call (``cascade_kernel.kalman_cascade``): the default model, with
        inertia and a kinematics or sensor lag if set (their inputs from ``_prepare``, compiled too).
        ``inertia_per_sample``: the cascade computes each sample's inertial force from the states before it
        (the mass and centre of mass as estimated then), as blocks of one sample would."""
        m, self._positions = len(block), block.p_BoEo_B  # (the payload watch reads the flange's motion)
        contiguous = np.ascontiguousarray  # (no-ops on the aligner's arrays; one compiled layout)
        t_ns = contiguous(block.t_ns, np.int64)
        inertial_S, stale, motion = None, contiguous(block.stale, bool), NO_MOTION
        if self.derivatives is not None or self.time_lag_s < 0:  # inertia, a kinematics or sensor lag
            force_S, torque_S, R_EB, inertial_S, known = self._prepare(block, usable=False, motion=inertia_per_sample)
            if known is not None:  # a late sensor stream's first samples: no pose yet, not used (as stale)
                stale = stale | ~known
            force_S, torque_S, R_EB = contiguous(force_S, float), contiguous(torque_S, float), contiguous(R_EB, float)
            if inertia_per_sample:  # _prepare gave the motion (m, 9): y_f and the inertial force are out
                motion, inertial_S = contiguous(inertial_S, float), np.empty((m, 3))
        else:
            force_S, torque_S = contiguous(block.force_S, float), contiguous(block.torque_S, float)
            R_EB = contiguous(block.R_EB, float)
            if self.gain_inverse_force is not None:
                force_S = force_S @ self.gain_inverse_force.T
            if self.gain_inverse_torque is not None:
                torque_S = torque_S @ self.gain_inverse_torque.T
        y_f = force_S if inertial_S is None else (force_S.copy() if len(motion) else force_S - inertial_S)
        if self.mount_rotation:  # R_EB in (a copy: the cascade writes R_SB through its mount estimate into it)
            A_f = np.array(R_EB, dtype=float, order="C")
        else:
            A_f = contiguous(self._to_S(R_EB)) if self.mount_configured else R_EB
        p_BoEo_B = NO_POSITIONS if block.p_BoEo_B is None else contiguous(block.p_BoEo_B, float)
        b, clock, limits = self._buffers, self._clock, self._limits
        b.ensure(m)
        if self._last_t_ns is not None:
            clock[0], clock[1] = 1, self._last_t_ns
        limits[0] = self.gate2
        if not (self._adapt[ADAPT_AUTO_F] and self._adapt[ADAPT_AUTO_T]):  # (auto bounds: the cascade's own)
            bound_f, bound_t = self._bounds()
            limits[1], limits[2] = bound_f * bound_f, bound_t * bound_t
        force, torque = self.force, self.torque
        out = Estimates(
            block.t_ns,
            np.empty((m, 3)),
            np.empty((m, 3)),
            np.empty(m, dtype=bool),
            np.empty(m, dtype=bool),
            np.empty(m, dtype=bool),
        )
        x_before = force.x.copy() if self.payload_change_ns > 0 else None
        failed_f, failed_t, gated_f, first_f, first_t = cascade_kernel.kalman_cascade(
            t_ns,
            clock,
            y_f,
            force_S,
            torque_S,
            A_f,
            stale,
            contiguous(block.status, np.int64),
            p_BoEo_B,
            NO_POSITIONS if inertial_S is None else inertial_S,
            motion,
            np.array([self._mass_known, self._cog_known], dtype=float),
            b.usable,
            force.x,
            force.P,
            torque.x,
            torque.P,
            force.q_bias,
            force.r,
            force.rc,
            torque.q_bias,
            torque.r,
            torque.rc,
            NO_RATE if force.q_rate is None else force.q_rate,
            NO_RATE if torque.q_rate is None else torque.q_rate,
            force.q_tilt,
            torque.q_tilt,
            cast("MountStage", force).R_SE if self.mount_rotation else self.R_SE,
            limits,
            self._adapt,
            self._information["force"],
            self._information["torque"],
            b.A_t,
            b.scratch,
            b.work,
            b.X_f,
            b.D_f,
            b.gated_f,
            b.failed_f,
            b.X_t,
            b.D_t,
            b.gated_t,
            b.failed_t,
            out.contact_force_S,
            out.contact_torque_S,
            out.contact,
            out.converged_force,
            out.converged_torque,
        )
        self._last_t_ns = int(t_ns[-1])
        if self.mount_rotation:
            self.R_SE = cast("MountStage", force).R_SE.copy()  # (the cascade turns force.R_SE in place)
        force.failed += failed_f
        torque.failed += failed_t
        if self._adapt[ADAPT_REOPEN_ROW] >= 0:  # (the block's last one: one event per block)
            self._torque_reopened(int(t_ns[int(self._adapt[ADAPT_REOPEN_ROW])]))
        self.converged_force, self.converged_torque = bool(out.converged_force[-1]), bool(out.converged_torque[-1])
        if self.payload_change_ns > 0 and (gated_f or self._payload.in_run):
            d2 = np.full(m, np.nan)  # (not kept by the cascade; the watcher does not use it)
            run_f = StageRun(b.X_f[:m], b.D_f[:m], b.gated_f[:m], d2, b.failed_f[:m])
            # (x_before was copied: payload_change_ns > 0)
            self._watch_payload(
                t_ns, y_f, force_S, torque_S, R_EB, A_f, b.usable[:m], run_f, cast(np.ndarray, x_before)
            )
        if self.first_converged_force is None and first_f >= 0:
            self.first_converged_force = self.samples + first_f
        if self.first_converged_torque is None and first_t >= 0:
            self.first_converged_torque = self.samples + first_t
        self.samples += m
        return out
