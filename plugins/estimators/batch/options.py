"""The ``batch`` estimator's options: one frozen record, checked once when it is made."""

from __future__ import annotations

from dataclasses import dataclass

from hapticlab.core.estimation.kernels import kernel_option
from hapticlab.core.estimation.model import MAX_FORCE, MAX_TORQUE, wrench_bound
from hapticlab.core.host.options import OptionError, choice, integer, is_number, number


@dataclass(frozen=True)
class BatchOptions:
    """The options of the ``batch`` estimator (SI units; the defaults are the fields').

    Attributes:
        calibration_samples: 0 refits over every sample seen so far; n > 0 fits the first n samples and
            then holds the parameters.
        force_threshold: residual norm (N) reported as contact (no gating: the batch method has none; the
            flag is for comparison only).
        torque_threshold: the same for torque (N·m).
        min_rcond: the fit counts as converged once the normal matrix, scaled to unit diagonal, has a
            reciprocal condition number of at least this (the poses seen so far determine every
            parameter); in [1e-12, 1]: below, a numerically singular fit would count as converged.
        max_force: a sample with a force component beyond this (N) is refused as implausible.
        max_torque: the same for a torque component (N·m).
        kernel: "numba" (the convergence flags proved by a Cholesky factorisation where it can,
            ``conditioned_kernel.py``, the same flags) or "numpy" (an SVD per sample, the reference).
        solver: "pinv" (numpy's pinv per sample: the reference's numbers) or "cholesky" (a Cholesky solve
            where the fit is proved well conditioned, pinv elsewhere: ~2x faster, not the same bits; the
            difference is measured in docs/estimators.md, "batch").
    """

    calibration_samples: int = 0
    force_threshold: float = 1.0
    torque_threshold: float = 0.1
    min_rcond: float = 1e-4
    max_force: float = MAX_FORCE
    max_torque: float = MAX_TORQUE
    kernel: str = "numba"
    solver: str = "pinv"

    def __post_init__(self) -> None:
        integer("calibration_samples", self.calibration_samples, minimum=0)
        number("force_threshold", self.force_threshold, above=0)
        number("torque_threshold", self.torque_threshold, above=0)
        if not (is_number(self.min_rcond) and 1e-12 <= self.min_rcond <= 1):
            raise OptionError(
                "min_rcond",
                "must be a number from 1e-12 to 1 (a reciprocal condition number: "
                "below 1e-12 a singular fit counts as converged, above 1 none ever does), "
                f"got {self.min_rcond!r}",
            )
        wrench_bound("max_force", self.max_force, MAX_FORCE)
        wrench_bound("max_torque", self.max_torque, MAX_TORQUE)
        kernel_option(self.kernel)
        choice("solver", self.solver, ("pinv", "cholesky"), hint=" (numpy's pinv, the reference)")
