"""The ``rls`` estimator's options: one frozen record, checked once when it is made.

Defaults are the paper's (Algorithm 1): P0 = 1e6·I, R = 2.5e-3·I, ε = 1e-3, and the contact thresholds
of its experiments. ``docs/estimators.md`` ("rls") measures what each option changes.
"""

from __future__ import annotations

from dataclasses import dataclass

from hapticlab.core.estimation.kernels import kernel_option
from hapticlab.core.estimation.model import MAX_FORCE, MAX_TORQUE, wrench_bound
from hapticlab.core.host.options import choice, integer, number


@dataclass(frozen=True)
class RLSOptions:
    """The options of the ``rls`` estimator (SI units; the defaults are the fields').

    Attributes:
        force_threshold: f_th, residual norm (N) from which a converged force stage treats a sample as
            contact and does not use it.
        torque_threshold: τ_th, the same for the torque stage (N·m).
        P0: initial covariance scale (P0·I).
        R: measurement-noise variance (R·I): N² for force, (N·m)² for torque.
        epsilon: convergence threshold on ‖Δx‖₂ (mixed units, as in Algorithm 1).
        seed: seed of the random initial estimates (the paper starts from random ones; seeded, runs repeat).
        covariance_update: "printed" (the default: P_k = (I − K_k C_k) P_{k−1} exactly as printed, eq. 28, so
            ``rls`` gives Algorithm 1's numbers, convergence decisions included) or "information" (the
            information form: the same estimate in exact arithmetic, without the printed update's rounding,
            which moves its convergence decisions; docs/estimators.md, "rls", measures the difference).
        max_force: a sample with a force component beyond this (N) is refused as implausible.
        max_torque: the same for a torque component (N·m).
        kernel: "numba" (the cascade compiled: ``covariance_form_kernel.py``, or ``information_form_kernel.py``
            for the information form) or "numpy" (the references, ``covariance_form.py``, ``information_form.py``).
    """

    force_threshold: float = 1.0
    torque_threshold: float = 0.1
    P0: float = 1e6
    R: float = 2.5e-3
    epsilon: float = 1e-3
    seed: int = 0
    covariance_update: str = "printed"
    max_force: float = MAX_FORCE
    max_torque: float = MAX_TORQUE
    kernel: str = "numba"

    def __post_init__(self) -> None:
        for key in ("force_threshold", "torque_threshold", "P0", "R", "epsilon"):
            number(key, getattr(self, key), above=0)
        integer("seed", self.seed, minimum=0)
        choice(
            "covariance_update",
            self.covariance_update,
            ("printed", "information"),
            hint=" (the paper's eq. 28 as printed)",
        )
        wrench_bound("max_force", self.max_force, MAX_FORCE)
        wrench_bound("max_torque", self.max_torque, MAX_TORQUE)
        kernel_option(self.kernel)
