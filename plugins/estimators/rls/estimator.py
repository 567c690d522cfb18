"""``rls``: the paper's cascaded recursive least squares, Algorithm 1 exactly.

Force stage: x = [gravity_force_B, bias_force_S], C_k = [R_EB, I3].
Torque stage, at samples where the force stage has converged:
x = [cog_S, bias_torque_S], C_k = [-skew(force_S - bias_force_S), I3].
P0 = 1e6·I, R = 2.5e-3·I, converged when ‖Δx‖ < ε = 1e-3; once converged,
a sample whose residual norm reaches the contact threshold is not used (the
stage is frozen during contact). The initial estimates are random, as in the
paper (seeded, so runs repeat).

Each stage runs the paper's printed update, P_k = (I − K_k C_k) P_{k−1}, one sample at a time
(``plugins.estimators.rls.covariance_form``), so the estimator gives Algorithm 1's numbers, its
convergence decisions included. ``covariance_update = "information"`` evaluates the same estimate in
information form (``plugins.estimators.rls.information_form``), without the printed update's rounding,
which moves some of its convergence decisions (docs/estimators.md, ``rls``, measures the difference).

Bad input (docs/estimators.md, "Refused samples"): a sample with a NaN or inf,
an R_EB that is not a rotation, or a force or torque component beyond
``max_force`` / ``max_torque`` is refused before either stage sees it, so the
stages hold exactly what they would hold had it never arrived (Algorithm 1
itself would take a NaN before convergence into x for good). Its row is NaN,
no contact, with the flags of the row before; ``refused_samples`` counts them
and ``drain_events()`` reports them (``sample_refused``). A solve that fails on
finite input leaves the stage as it was and marks that sample not converged.

Kernel (``kernel``, docs/estimators.md): ``"numba"`` (the default) runs both stages and the
contact wrench of each block in one compiled call (``covariance_form_kernel.py``, held to
``algorithm1`` bit for bit; ``information_form_kernel.py`` for the information form); ``"numpy"`` runs
the references above, which the tests compare them to.

Nothing here improves on the paper: improvements are other estimators or
named options elsewhere, so the paper's method stays measurable.
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from hapticlab.core.estimation.model import RefusesBadSamples, SampleGuard, contact_wrench, named_params
from hapticlab.core.frames import skew_stack
from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.plugins.estimators.rls import covariance_form_kernel as printed_kernel
from hapticlab.plugins.estimators.rls import information_form_kernel as rls_kernel
from hapticlab.plugins.estimators.rls.covariance_form import PrintedRecursiveLeastSquares
from hapticlab.plugins.estimators.rls.information_form import RecursiveLeastSquares, RLSStage, run_gated
from hapticlab.plugins.estimators.rls.options import RLSOptions


class RLSEstimator(RefusesBadSamples):
    """Cascaded RLS of the non-contact wrench (paper, Algorithm 1).

    Options: :class:`RLSOptions` (``RLSEstimator(force_threshold=0.6)`` or ``RLSEstimator(options)``).

    Attributes:
        force, torque: the two stages (``PrintedRecursiveLeastSquares``, or ``RecursiveLeastSquares`` with
            ``covariance_update = "information"``).
        converged_force, converged_torque: the stages' flags as Algorithm 1
            keeps them (recomputed at every sample a stage uses).
        first_converged_force, first_converged_torque: index of the sample at
            which each flag first became true (None until then).
        samples: samples seen, refused ones included (the first_converged
            indices count them too: they are rows of the estimates).
        refused_samples: samples refused as bad input (never given to a stage).
        failed_solves: samples a stage could not solve for (left out, not converged).
    """

    Options = RLSOptions

    def __init__(self, options: RLSOptions | None = None, /, **settings: Any):
        o = self.options = options if options is not None else RLSOptions(**settings)
        force_threshold, torque_threshold, epsilon, P0, R = o.force_threshold, o.torque_threshold, o.epsilon, o.P0, o.R
        covariance_update, kernel = o.covariance_update, o.kernel
        self.kernel = kernel
        self.guard = SampleGuard("rls", o.max_force, o.max_torque)
        stage = PrintedRecursiveLeastSquares if covariance_update == "printed" else RecursiveLeastSquares
        rng = np.random.default_rng(o.seed)
        self.force_threshold = force_threshold
        self.torque_threshold = torque_threshold
        self.epsilon = epsilon
        self.covariance_update = covariance_update
        self.P0 = P0
        self.force: RLSStage = stage(rng.standard_normal(6), P0, R)
        self.torque: RLSStage = stage(rng.standard_normal(6), P0, R)
        self.restarts = 0
        self.converged_force = False
        self.converged_torque = False
        self.first_converged_force: int | None = None
        self.first_converged_torque: int | None = None
        self.samples = 0
        self._compiled = kernel == "numba"
        self._printed = covariance_update == "printed"
        if self._compiled and self._printed:  # what the kernel needs, allocated once
            printed_kernel.warm_up()
            self._settings = np.array([R, R, force_threshold, torque_threshold, epsilon])
            self._status = printed_kernel.status_array()
            self._work = printed_kernel.work_arrays()
        elif self._compiled:
            rls_kernel.warm_up()
            force, torque = cast(RecursiveLeastSquares, self.force), cast(RecursiveLeastSquares, self.torque)
            self._settings = np.array([1.0 / force.r, 1.0 / torque.r, force_threshold, torque_threshold, epsilon])
            self._status = rls_kernel.status_array()
            self._work = rls_kernel.work_arrays()
            self._diag = np.empty(6)  # diag P_force, for force_parameter_std

    def update_block(self, block: AlignedSamples) -> Estimates:
        """Run Algorithm 1 over a block of aligned samples, in order (bad samples refused first)."""
        out = self.guard.run(block, self._update, (self.converged_force, self.converged_torque))
        self._note_first(out.converged_force, out.converged_torque)
        self.samples += len(block)
        return out

    def _update(self, block: AlignedSamples) -> Estimates:
        """Algorithm 1 over samples that passed the guard."""
        if self._compiled:
            return self._update_compiled(block)
        force_S, torque_S, R_EB = block.force_S, block.torque_S, block.R_EB
        X_f, conv_f, gated_f, self.converged_force = run_gated(
            self.force,
            force_S,
            R_EB,
            np.ones(len(block), dtype=bool),
            self.force_threshold,
            self.epsilon,
            self.converged_force,
        )
        A_t = -skew_stack(force_S - X_f[:, 3:])  # C_k = [-skew(Δf), I3]
        X_t, conv_t, gated_t, self.converged_torque = run_gated(
            self.torque, torque_S, A_t, conv_f, self.torque_threshold, self.epsilon, self.converged_torque
        )
        contact_force_S, contact_torque_S = contact_wrench(force_S, torque_S, R_EB, X_f, X_t)
        return Estimates(
            t_ns=block.t_ns,
            contact_force_S=contact_force_S,
            contact_torque_S=contact_torque_S,
            contact=gated_f | gated_t,
            converged_force=conv_f,
            converged_torque=conv_t,
        )

    def _update_compiled(self, block: AlignedSamples) -> Estimates:
        """``_update`` by the compiled kernel: the stages' x and P (printed) or x, Λ, η updated in place."""
        m = len(block)
        status = self._status
        status[0], status[1], status[2:] = self.converged_force, self.converged_torque, 0
        wrench, flags = np.empty((2, m, 3)), np.empty((3, m), dtype=bool)  # (rows of each are contiguous)
        contiguous = np.ascontiguousarray  # (a no-op on the aligner's arrays; one compiled layout)
        data = contiguous(block.force_S, float), contiguous(block.torque_S, float), contiguous(block.R_EB, float)
        if self._printed:
            pf, pt = cast(PrintedRecursiveLeastSquares, self.force), cast(PrintedRecursiveLeastSquares, self.torque)
            printed_kernel.printed_cascade(
                *data,
                pf.x,
                pf.P,
                pf.K,
                pt.x,
                pt.P,
                pt.K,
                self._settings,
                status,
                self._work,
                printed_kernel.DGESV,
                wrench,
                flags,
            )
        else:
            force, torque = cast(RecursiveLeastSquares, self.force), cast(RecursiveLeastSquares, self.torque)
            rls_kernel.rls_cascade(
                *data,
                force.x,
                force.Lambda,
                force.eta,
                torque.x,
                torque.Lambda,
                torque.eta,
                self._settings,
                status,
                self._work,
                rls_kernel.DPOSV,
                wrench,
                flags,
            )
        out = Estimates(block.t_ns, wrench[0], wrench[1], flags[0], flags[1], flags[2])
        u_f, f_f, u_t, f_t = status[2:6].tolist()
        self.converged_force, self.converged_torque = bool(status[0]), bool(status[1])
        self.force.updates += u_f
        self.force.failed += f_f
        self.torque.updates += u_t
        self.torque.failed += f_t
        return out

    def _note_first(self, conv_f: np.ndarray, conv_t: np.ndarray) -> None:
        if self.first_converged_force is None and conv_f.any():
            self.first_converged_force = self.samples + int(np.argmax(conv_f))
        if self.first_converged_torque is None and conv_t.any():
            self.first_converged_torque = self.samples + int(np.argmax(conv_t))

    def reidentify_bias(self, reason: str) -> None:
        """Reidentifies: run Algorithm 1 again from the current estimate (both stages' P back to P0·I, flags
        down), as the paper's method would be restarted; the host asks for it after a sensor bias step."""
        for stage in (self.force, self.torque):
            stage.restart(self.P0)
        self.converged_force = self.converged_torque = False
        self.restarts += 1

    def reidentify_weight(self, reason: str) -> None:
        """ReidentifiesWeight: Algorithm 1 restarted as for a bias step (its restart re-opens every parameter)."""
        self.reidentify_bias(reason)

    def params(self) -> dict[str, list[float]]:
        """Identified parameters with physical names (SI units)."""
        return named_params(self.force.x, self.torque.x)

    def force_parameter_std(self) -> np.ndarray:
        """(6,) standard deviation of [gravity_force_B, bias_force_S], N: sqrt of diag P_force.

        P is scaled by the paper's R (2.5e-3 N²), so this measures how well the
        poses seen so far determine each parameter, not the sensor's noise. The haptic gate asks every
        tick. The printed update (the default) keeps P itself; its rounding can leave a diagonal entry
        negative for a few samples (after a restart, at random orientations), and the std is then NaN, which
        the gate takes as not known. The information form's compiled path takes diag(Λ⁻¹) from a Cholesky
        factor (``rls_kernel.inverse_diag``), and inverts Λ as ``P`` does where it is not positive definite.
        """
        return np.sqrt(self._P_diag(self.force))

    def cov_diag(self) -> list[float]:
        """Diagonal of P for the force stage then the torque stage (12 values)."""
        return self._P_diag(self.force).tolist() + self._P_diag(self.torque).tolist()

    def _P_diag(self, stage: RLSStage) -> np.ndarray:
        """(6,) diag P of a stage: P's own (printed), or diag Λ⁻¹ (information: by Cholesky when compiled)."""
        # (compiled: the information form's stage)
        if (
            self._compiled
            and not self._printed
            and rls_kernel.inverse_diag(cast(RecursiveLeastSquares, stage).Lambda, self._work[1], self._diag)
        ):
            return self._diag
        return np.diag(stage.P)
