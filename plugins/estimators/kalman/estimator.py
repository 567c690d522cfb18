"""``kalman``: the paper's cascade as Kalman filters, with drifting biases, Mahalanobis gating and
convergence from what is known.

Force stage: x = [gravity_force_B, bias_force_S], C_k = [R_EB, I3]. Torque stage, at every sample the force
stage accepts: x = [cog_S, b'], b' = bias_torque_S - cog_S × bias_force_S, C_k = [-skew(force_S), I3]
(``torque_bias.py``). Unlike the paper's RLS, the biases are random walks (in time
and with the tool's tilt), R is the sensor's noise (estimated as it runs, or given), a sample outside
``gate_probability`` of its predicted distribution is refused (time still propagates, so the gate reopens
on a bias that has truly moved), and convergence comes from what is known, never from a small step.

This file builds the estimator and runs the numpy reference (``_filter_block``); the parts it is put
together from are ``compiled.py`` (the compiled path, the default), ``inputs.py``, ``convergence.py``,
``reopen.py`` and ``warm_start.py``. ``docs/estimators.md`` ("kalman") has the measurements behind every
default.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
from scipy.special import gammaincinv

from hapticlab.core import aligner_kernel
from hapticlab.core.estimation.model import RefusesBadSamples, SampleGuard, contact_wrench
from hapticlab.core.frames import cross, skew_stack
from hapticlab.core.types import AlignedSamples, Estimates, Event
from hapticlab.plugins.estimators.kalman import cascade_kernel, derivatives_kernel, identified
from hapticlab.plugins.estimators.kalman.compiled import CompiledPath
from hapticlab.plugins.estimators.kalman.convergence import Convergence
from hapticlab.plugins.estimators.kalman.derivatives import MotionDerivatives
from hapticlab.plugins.estimators.kalman.inputs import ModelInputs
from hapticlab.plugins.estimators.kalman.mount_stage import MountStage
from hapticlab.plugins.estimators.kalman.noise import (
    NOISE_AUTO_START_FORCE,
    NOISE_AUTO_START_TORQUE,
    NOISE_FLOOR,
    NOISE_REFUSED_WEIGHT,
    NOISE_WINDOW,
    adapt_noise,
    window_samples,
)
from hapticlab.plugins.estimators.kalman.options import (
    TORQUE_PER_FORCE,
    KalmanOptions,
    gain_inverse,
    mount_matrix,
    noise_axes,
)
from hapticlab.plugins.estimators.kalman.payload import PayloadWatch
from hapticlab.plugins.estimators.kalman.reopen import Reopening
from hapticlab.plugins.estimators.kalman.rules_kernel import judge_contact, set_gravity_direction, tilt_step
from hapticlab.plugins.estimators.kalman.stage import KalmanStage, innovations
from hapticlab.plugins.estimators.kalman.state_layout import (
    ADAPT_CAP_F,
    ADAPT_CAP_T,
    ADAPT_COUNT_F,
    ADAPT_COUNT_T,
    ADAPT_FORCE_SEEN,
    ADAPT_GRAVITY_DIR,
    ADAPT_GRAVITY_KNOWN,
    ADAPT_HELD_OUT,
    ADAPT_TORQUE_SEEN,
    ADAPT_TW,
    ADAPT_WINDOW,
    new_state,
)
from hapticlab.plugins.estimators.kalman.tilt_walk_kernel import learn_tilt_walk
from hapticlab.plugins.estimators.kalman.warm_start import WarmStart

BIAS_RATE_PRIOR_FORCE = 0.025
"""Prior std of the force-bias rate, N/s (three times the 0.5 N/min drift figure)."""
BIAS_RATE_PRIOR_TORQUE = 0.002
"""Prior std of the torque-bias rate, N·m/s (the force figure times 0.077 m)."""


class KalmanEstimator(CompiledPath, ModelInputs, Convergence, Reopening, WarmStart, RefusesBadSamples):
    """Cascaded Kalman filters of the non-contact wrench, with drifting biases.

    Options: :class:`KalmanOptions` (``KalmanEstimator(noise_force=0.12)`` or ``KalmanEstimator(options)``).

    Attributes:
        force, torque: the two KalmanStage stages.
        converged_force, converged_torque: the stages' flags after the last sample.
        first_converged_force, first_converged_torque: index of the sample at
            which each flag first became true (None until then).
        samples: samples seen, refused ones included (the first_converged
            indices count them too: they are rows of the estimates).
        refused_samples: samples refused as bad input (never given to a stage).
        failed_solves: samples whose update could not be computed (S singular or
            not positive definite): predicted only, marked not converged.
        gate2: the gate on the squared Mahalanobis distance.
    """

    Options = KalmanOptions

    def __init__(self, options: KalmanOptions | None = None, /, **settings: Any):
        o = self.options = options if options is not None else KalmanOptions(**settings)
        bias_rate, mount_rotation, inertia = o.resolved_bias_rate, o.resolved_mount_rotation, o.resolved_inertia
        bias_force_tilt_rw, bias_torque_tilt_rw = o.resolved_force_tilt_rw, o.bias_torque_tilt_rw
        # "auto": the stage's noise estimated as it runs (noise.py), each stage on its own
        self.noise_auto_force, self.noise_auto_torque = o.noise_force == "auto", o.noise_torque == "auto"
        self.noise_auto = self.noise_auto_force or self.noise_auto_torque
        noise_force = (
            np.full(3, NOISE_AUTO_START_FORCE) if self.noise_auto_force else noise_axes("noise_force", o.noise_force)
        )
        noise_torque = (
            np.full(3, NOISE_AUTO_START_TORQUE)
            if self.noise_auto_torque
            else noise_axes("noise_torque", o.noise_torque)
        )
        # "auto": the tilt walk's intensity learnt from the data (tilt_walk_kernel), the torque's following
        self.tilt_walk_auto = bias_force_tilt_rw == "auto"
        tilt_torque_follows = bias_torque_tilt_rw is None
        if self.tilt_walk_auto:
            bias_force_tilt_rw = 0.0  # (until the first pair of windows is scored)
        if bias_torque_tilt_rw is None:
            bias_torque_tilt_rw = cast(float, bias_force_tilt_rw) * TORQUE_PER_FORCE  # ("auto" is 0.0 by now)
        self.kernel = o.kernel
        R_SE = mount_matrix(o.mount_rotation_SE, o.mount_R_SE)
        self.guard = SampleGuard("kalman", o.max_force, o.max_torque)
        self.gain_inverse_force = gain_inverse("gain_force_S", o.gain_force_S)
        self.gain_inverse_torque = gain_inverse("gain_torque_S", o.gain_torque_S)

        self.bias_rate = bias_rate
        self.mount_rotation = mount_rotation
        self.mount_configured = o.mount_rotation_SE is not None or o.mount_R_SE is not None
        self.R_SE = R_SE
        self.inertia = inertia
        self.time_lag_s = float(o.time_lag_s)
        self.effects = sorted(
            set(o.effects or [])
            | ({"bias_drift"} if bias_rate else set())
            | ({"mount_rotation"} if mount_rotation else set())
            | ({"inertia"} if inertia else set())
            | ({"time_lag"} if o.time_lag_s else set())
            | ({"gain_crosstalk"} if o.gain_force_S is not None or o.gain_torque_S is not None else set())
        )
        derivatives = derivatives_kernel.CompiledMotionDerivatives if o.kernel == "numba" else MotionDerivatives
        self.derivatives = derivatives(o.derivative_window_s) if (inertia or o.time_lag_s > 0) else None
        self._lag_t = np.zeros(0, dtype=np.int64)  # the poses a late sensor stream still needs (time_lag_s < 0)
        self._lag_q = np.zeros((0, 4))
        self._lag_p: np.ndarray | None = np.zeros((0, 3))
        self.method = None if o.implementation == "auto" else o.implementation
        if o.kernel == "numba" and o.implementation in ("auto", "fast") and not bias_rate:
            self.method = "numba"  # (the torque stage's with mount_rotation)
        chi2_3 = 2 * gammaincinv(1.5, o.gate_probability)  # chi2.ppf(p, 3) bit for bit, without scipy.stats' import
        self.gate2 = math.inf if (o.gate_probability == 1 or o.gating == "none") else float(chi2_3)
        self.convergence = o.convergence
        self.converged_force_std_option = o.converged_force_std
        self.converged_torque_std_option = o.converged_torque_std
        rate_f = [o.bias_force_rate_rw] * 3 if bias_rate else None
        rate_t = [o.bias_torque_rate_rw] * 3 if bias_rate else None
        prior_f = [o.prior_force_std] * 6 + ([BIAS_RATE_PRIOR_FORCE] * 3 if bias_rate else [])
        prior_t = [o.prior_cog_std] * 3 + [o.prior_torque_std] * 3 + ([BIAS_RATE_PRIOR_TORQUE] * 3 if bias_rate else [])
        if mount_rotation:
            self.force = MountStage(
                prior_f,
                [o.bias_force_rw] * 3,
                noise_force,
                R_SE,
                o.mount_prior_std,
                bias_rate_rw=rate_f,
                bias_tilt_rw=[bias_force_tilt_rw] * 3,
                tilt_span=o.bias_tilt_span,
            )
        else:
            self.force = KalmanStage(
                prior_f,
                [o.bias_force_rw] * 3,
                noise_force,
                bias_rate_rw=rate_f,
                bias_tilt_rw=[bias_force_tilt_rw] * 3,
                tilt_span=o.bias_tilt_span,
            )
        self.torque = KalmanStage(
            prior_t,
            [o.bias_torque_rw] * 3,
            noise_torque,
            cross_noise=noise_force,
            bias_rate_rw=rate_t,
            bias_tilt_rw=[bias_torque_tilt_rw] * 3,
            tilt_span=o.bias_tilt_span,
        )
        self.converged_force = False
        self.converged_torque = False
        self.first_converged_force: int | None = None
        self.first_converged_torque: int | None = None
        self.samples = 0
        self._last_t_ns: int | None = None
        self._cog_known = False  # a warm start's torque stage had converged
        self._mass_known = False  # a warm start's force stage had converged
        self.prior_f = np.array(prior_f, dtype=float)
        self.prior_t = np.array(prior_t, dtype=float)
        self.payload_change_ns = round(o.payload_change_s * 1e9)
        self.torque_reopen_s, self.torque_early = float(o.torque_reopen_s), o.torque_start == "early"
        # the noise estimate's, the identified rule's, the contact judge's and the tilt walk's state, in the
        # compiled cascade's layout (both paths use it)
        self._adapt = new_state(
            o,
            noise_auto=(self.noise_auto_force, self.noise_auto_torque),
            tilt_walk_auto=self.tilt_walk_auto,
            tilt_torque_follows=tilt_torque_follows,
            prior_torque_bias_var=self.prior_t[3:6] ** 2,
            mount_activate_var=cast(MountStage, self.force).activate_var if mount_rotation else 0.0,
        )
        self.events: list[Event] = []
        self._unidentified = {"gravity_force_B": (0, 1, 2), "cog_S": (0, 1, 2)}  # as last reported (events)
        self.payload_changes = 0
        self._payload = PayloadWatch(self.payload_change_ns)  # the force stage's refusal runs
        # the rules that follow what the motion identifies ("pose" flags the wrench at the pose, and reports
        # the identification beside it, as "identified" does)
        self.identifies = o.convergence in ("identified", "pose")
        self._per_sample = self.noise_auto or self.identifies or self.tilt_walk_auto  # (the numpy reference's blocks)
        self._information: dict[str, np.ndarray] = {}  # the identification: Λ per stage (6, 6)
        self._seed_information()
        if o.warm_start:
            self.load_state(o.warm_start)
        # the whole cascade in one compiled call (the step rule runs per stage); with bias-rate states and a mount
        # estimate too (stage_kernel.stage_step_rate, stage_step_mount; the stage runs a payload replay makes stay
        # the numpy ones)
        compiled = self.method == "numba" or (o.kernel == "numba" and o.implementation == "auto" and bias_rate)
        self._cascade = compiled and o.convergence != "step"
        if o.kernel == "numba":
            derivatives_kernel.warm_up()
            if self.time_lag_s < 0:
                aligner_kernel.warm_up()
        if self.method == "numba" or self._cascade:
            cascade_kernel.warm_up()
            self._buffers = cascade_kernel.Buffers()
            self._clock = np.zeros(2, dtype=np.int64)  # [a sample came before, its t_ns]
            self._limits = np.zeros(3)  # [gate2, bound_f², bound_t²]
            self._L6 = np.empty((6, 6))  # constant_var3's Cholesky factor

    def update_block(self, block: AlignedSamples) -> Estimates:
        """Filter a block of aligned samples, in order (bad samples refused first)."""
        start, first = self.samples, (self.first_converged_force, self.first_converged_torque)
        extras: tuple[np.ndarray, ...] = ()
        if self.derivatives is not None or self.time_lag_s < 0:  # the pose's quaternion and position are used
            extras = tuple(a for a in (block.quat_BE, block.p_BoEo_B) if a is not None)
        out = self.guard.run(block, self._filter_block, (self.converged_force, self.converged_torque), extras)
        if self.identifies and len(block):
            self._watch_identified(int(block.t_ns[-1]))
        if self.samples != start + len(block):
            # samples refused: the filter counted the accepted ones; the indices are rows of the block
            if first[0] is None and self.first_converged_force is not None:
                self.first_converged_force = start + int(np.argmax(out.converged_force))
            if first[1] is None and self.first_converged_torque is not None:
                self.first_converged_torque = start + int(np.argmax(out.converged_torque))
            self.samples = start + len(block)
        return out

    def _filter_block(self, block: AlignedSamples) -> Estimates:
        """Filter a block of samples that passed the guard, in order."""
        m, self._positions = len(block), block.p_BoEo_B  # (the payload watch reads the flange's motion)
        # the noise estimate and the identified rule follow sample by sample: the reference runs them one
        # sample at a time, the compiled cascade in its loop (the inertial force too, from the mass and
        # centre of mass estimated before each sample)
        if self._per_sample and m > 1 and not self._cascade:
            return Estimates.concatenate([self._filter_block(block.subset(slice(i, i + 1))) for i in range(m)])
        if self._cascade and m:
            return self._filter_compiled(block, inertia_per_sample=self._per_sample and self.inertia and m > 1)
        if m == 0:
            empty = np.zeros((0, 3))
            flags = np.zeros(0, dtype=bool)
            return Estimates(block.t_ns, empty, empty.copy(), flags, flags.copy(), flags.copy())
        t_ns = np.asarray(block.t_ns, dtype=np.int64)
        dt_ns = np.empty(m, dtype=np.int64)
        dt_ns[0] = 0 if self._last_t_ns is None else t_ns[0] - self._last_t_ns
        dt_ns[1:] = t_ns[1:] - t_ns[:-1]
        dt = np.maximum(dt_ns, 0) * 1e-9  # s; a repeated or reversed stamp adds no time
        self._last_t_ns = int(t_ns[-1])
        usable = block.usable
        force_S, torque_S, R_EB, inertial_S, usable = self._prepare(block)  # type: ignore[assignment]  # an array with usable=True
        y_f = force_S if inertial_S is None else force_S - inertial_S  # what gravity and bias explain

        x_before = self.force.x[:6].copy()
        tilt = None  # rad, before each sample, with the tilt walk on
        if self.force.q_tilt.any() or self.torque.q_tilt.any() or self.tilt_walk_auto:
            tilt = np.array([tilt_step.py_func(self._adapt, R) for R in R_EB])
        if self.mount_rotation:  # the stage applies its own mount estimate, updated as it goes
            run_f = self.force.run(y_f, R_EB, dt, usable, self.gate2, tilt=tilt)
            self.R_SE = cast(MountStage, self.force).R_SE
            A_f = self._to_S(R_EB)  # R_SB per sample, with the mount as it is after the block
        else:
            A_f = self._to_S(R_EB)  # R_SB per sample
            run_f = self.force.run(y_f, A_f, dt, usable, self.gate2, self.method, tilt)
        X_f = run_f.X
        A_t = -skew_stack(force_S)  # C_k = [-skew(f), I3] about the measured force (torque_bias.py)
        if run_f.failed is not None:  # updates that could not be computed: not used, not converged
            usable = usable & ~run_f.failed
        accepted_f = usable & ~run_f.gated
        conv_f, settled_f = self._force_converged(run_f, x_before, accepted_f, A_f)
        if run_f.failed is not None:
            conv_f &= ~run_f.failed
            settled_f &= ~run_f.failed
        x_t_before = self.torque.x[:6].copy()
        seen_t = (force_seen := accepted_f & settled_f) | (accepted_f & self.torque_early)  # (settled; early: all)
        run_t = self.torque.run(torque_S, A_t, dt, seen_t, self.gate2, self.method, tilt)
        if run_t.failed is not None:
            seen_t = seen_t & ~run_t.failed
        accepted_t = seen_t & ~run_t.gated
        conv_t, settled_t = self._torque_converged(run_t, X_f, x_t_before, accepted_t, A_t)
        if run_t.failed is not None:
            conv_t &= ~run_t.failed
            settled_t &= ~run_t.failed
        if self.torque_early:  # (started early: its flag and its settling still wait for the force stage's)
            conv_t, settled_t = conv_t & conv_f, settled_t & settled_f
        if settled_t.any():  # (at the pose: the centre of gravity identified as well)
            self._adapt[ADAPT_TORQUE_SEEN] = 1.0
        torque_for_contact = torque_S - cross(run_t.X[:, :3], X_f[:, 3:6])  # (b' is about f: torque_bias.py)
        if inertial_S is not None:  # the inertial force acts at the centre of mass like the weight
            torque_for_contact = torque_for_contact - cross(run_t.X[:, :3], inertial_S)
        contact_force_S, contact_torque_S = contact_wrench(y_f, torque_for_contact, A_f, X_f[:, :6], run_t.X[:, :6])
        if self.torque_reopen_s > 0:
            self._watch_torque_only(t_ns, run_f.gated, force_seen, run_t, dt, contact_force_S, contact_torque_S)
        if self.noise_auto:
            if self._adapt[ADAPT_WINDOW] == 0 and dt[0] > 0:  # the sensor's rate, from the first time step
                self._adapt[ADAPT_WINDOW] = window_samples(float(dt[0]))
            if self.noise_auto_force:
                self._adapt_noise(self.force, y_f, A_f, x_before, run_f, usable, ADAPT_COUNT_F)
            if self.noise_auto_torque:  # (with the force noise it carried at this sample)
                self._adapt_noise(self.torque, torque_S, A_t, x_t_before, run_t, seen_t, ADAPT_COUNT_T)
            self.torque.rc = self.force.r.copy()

        self.converged_force, self.converged_torque = bool(conv_f[-1]), bool(conv_t[-1])
        if self.payload_change_ns > 0:
            self._watch_payload(t_ns, y_f, force_S, torque_S, R_EB, A_f, usable, run_f, x_before)
        if self.first_converged_force is None and conv_f.any():
            self.first_converged_force = self.samples + int(np.argmax(conv_f))
        if not self._adapt[ADAPT_FORCE_SEEN] and settled_f.any():  # (at the pose: identified as well)
            if self.noise_auto:
                self._adapt[[ADAPT_CAP_F, ADAPT_CAP_T]] = self._bounds()
            self._adapt[ADAPT_FORCE_SEEN] = 1.0
            if not self._adapt[ADAPT_GRAVITY_KNOWN]:  # tilts about the identified weight
                set_gravity_direction.py_func(self._adapt, self.force.x[:3])
        if self.tilt_walk_auto:
            self._learn_tilt_walk(y_f, A_f, t_ns, run_f.gated, usable)  # (the force stage's own: not the torque's)
        if self.first_converged_torque is None and conv_t.any():
            self.first_converged_torque = self.samples + int(np.argmax(conv_t))
        self.samples += m
        return Estimates(
            t_ns=block.t_ns,
            contact_force_S=contact_force_S,
            contact_torque_S=contact_torque_S,
            contact=self._judge_contacts(run_f.gated | run_t.gated, usable),
            converged_force=conv_f,
            converged_torque=conv_t,
        )

    def _learn_tilt_walk(self, y_f, A_f, t_ns, refused, tested) -> None:
        """The tilt walk's intensity from the block's samples (``tilt_walk_kernel.learn_tilt_walk``, run as Python, as
        the cascade runs it after each sample): into both stages' q_tilt, the torque's times ``TORQUE_PER_FORCE``²
        unless it was given. The reference filters one sample per block here, so x is the sample's."""
        if not self._adapt[ADAPT_FORCE_SEEN]:
            return
        learn, tw = learn_tilt_walk.py_func, self._adapt[ADAPT_TW:]
        g_B = self._adapt[ADAPT_GRAVITY_DIR : ADAPT_GRAVITY_DIR + 3]
        q_bias = self.force.q_bias
        q_time = (q_bias[0] + q_bias[1] + q_bias[2]) / 3.0
        for k in range(len(t_ns)):
            if tested[k]:
                self._set_tilt_walk(
                    learn(tw, y_f[k], A_f[k], self.force.x, g_B, t_ns[k] * 1e-9, bool(refused[k]), q_time)
                )

    def _judge_contacts(self, refused: np.ndarray, tested: np.ndarray) -> np.ndarray:
        """(m,) the refused samples judged a contact (``rules_kernel.judge_contact``, run as Python); ``tested``:
        the samples a stage tested (the others neither continue nor end a refused run)."""
        judge = judge_contact.py_func
        return np.array([judge(self._adapt, r, t) for r, t in zip(refused.tolist(), tested.tolist())], dtype=bool)

    @property
    def held_out_samples(self) -> int:
        """Samples of the refused runs that ended before they were judged a contact: lone outliers of the
        sensor's noise (see ``contact_after``; a run still going is counted when it ends)."""
        return int(self._adapt[ADAPT_HELD_OUT])

    def _adapt_noise(self, stage, y, A, x_before, run, usable, counter: int) -> None:
        """One sample's covariance matching (``plugins.estimators.kalman.noise``; the numpy reference runs ``noise =
        "auto"`` one sample at a time): e at the state the sample was predicted from, C P Cᵀ with the
        stage's P after it (for the torque stage plus the force noise it carries through the centre of
        gravity, which its R adds separately)."""
        if not usable[0]:
            return
        e = innovations(y, A, x_before, run.X)[0]
        cpc = identified.predicted_var(stage.P, A[0])
        cpc += stage.measurement_cov(stage.x[:3]).diagonal() - stage.r  # the torque stage's carried force noise
        # refused samples count only until the force stage first converged (plugins.estimators.kalman.noise)
        weight = 1.0 if not run.gated[0] else (NOISE_REFUSED_WEIGHT if not self._adapt[ADAPT_FORCE_SEEN] else 0.0)
        floor = NOISE_FLOOR[0] if stage is self.force else NOISE_FLOOR[1]
        window = self._adapt[ADAPT_WINDOW] or NOISE_WINDOW
        stage.r, self._adapt[counter] = adapt_noise(stage.r, self._adapt[counter], e, cpc, weight, window, floor)

    def drain_events(self) -> list[Event]:
        """The events since the last call (EmitsEvents): ``payload_change``, ``sample_refused``."""
        out, self.events = self.events + self.guard.drain_events(), []
        return out
