"""What every part of the ``kalman`` estimator shares: its attributes, and the small methods they all call.

:class:`KalmanEstimator` is put together from parts, one file each (``inputs.py``, ``convergence.py``,
``reopen.py``, ``warm_start.py``); each part derives from :class:`KalmanBase`, which names the state
they read and write (set once by ``KalmanEstimator.__init__``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from hapticlab.core.types import Event
from hapticlab.plugins.estimators.kalman.options import KalmanOptions
from hapticlab.plugins.estimators.kalman.payload import PayloadWatch
from hapticlab.plugins.estimators.kalman.stage import KalmanStage
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_TILT_TORQUE

if TYPE_CHECKING:
    from hapticlab.core.estimation.model import SampleGuard
    from hapticlab.core.types import AlignedSamples
    from hapticlab.plugins.estimators.kalman.cascade_kernel import Buffers
    from hapticlab.plugins.estimators.kalman.derivatives import MotionDerivatives
    from hapticlab.plugins.estimators.kalman.stage import StageRun


class KalmanBase:
    """The attributes the estimator's parts share, and the methods more than one of them calls."""

    force: KalmanStage  # a MountStage with mount_rotation
    torque: KalmanStage
    options: KalmanOptions
    guard: SampleGuard
    kernel: str
    method: str | None
    convergence: str
    identifies: bool
    mount_rotation: bool
    mount_configured: bool
    bias_rate: bool
    inertia: bool
    effects: list[str]
    gain_inverse_force: np.ndarray | None
    gain_inverse_torque: np.ndarray | None
    derivatives: MotionDerivatives | None
    noise_auto: bool
    noise_auto_force: bool
    noise_auto_torque: bool
    tilt_walk_auto: bool
    time_lag_s: float
    gate2: float
    R_SE: np.ndarray
    prior_f: np.ndarray
    prior_t: np.ndarray
    converged_force: bool
    converged_torque: bool
    first_converged_force: int | None
    first_converged_torque: int | None
    samples: int
    converged_force_std_option: float | None
    converged_torque_std_option: float | None
    torque_reopen_s: float
    payload_change_ns: int
    payload_changes: int
    _positions: np.ndarray | None = None  # the block's flange positions, m in B (the payload watch's)
    events: list[Event]
    _adapt: np.ndarray
    _information: dict[str, np.ndarray]
    _unidentified: dict[str, tuple[int, ...]]
    _last_t_ns: int | None
    _cog_known: bool
    _mass_known: bool
    _payload: PayloadWatch
    _lag_t: np.ndarray
    _lag_q: np.ndarray
    _lag_p: np.ndarray | None
    _per_sample: bool
    _cascade: bool
    _buffers: Buffers
    _clock: np.ndarray
    _limits: np.ndarray
    _L6: np.ndarray

    def _force_biases(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The force stage's bias (3,) N and, with ``bias_rate``, its rate (3,) N/s: what ``torque_bias`` needs."""
        return self.force.x[3:6], (self.force.x[6:9] if self.bias_rate else None)

    def _seed_information(self) -> None:
        """Λ of each stage from its current P (6×6: the constant and the bias): at the start, and after a
        payload change, a bias re-identification or a warm start re-opened or set what is known."""
        for name, stage in (("force", self.force), ("torque", self.torque)):
            self._information[name] = np.linalg.inv(stage.P[:6, :6])

    def _set_tilt_walk(self, q: float) -> None:
        """The learnt walk q (N²/rad) into the force stage's q_tilt, and times ``TORQUE_PER_FORCE``² into the
        torque stage's unless that was given (as the cascade writes qt_f and qt_t)."""
        self.force.q_tilt[:] = q
        if self._adapt[ADAPT_TILT_TORQUE] >= 0.0:
            self.torque.q_tilt[:] = q * self._adapt[ADAPT_TILT_TORQUE]

    def params(self) -> dict[str, list[float]]:
        """The identified parameters (``Convergence.params``)."""
        raise NotImplementedError

    # one part's methods that another part calls: each defined by the part its docstring names

    def _to_S(self, R_EB: np.ndarray) -> np.ndarray:
        """(m, 3, 3) R_SB = R_SE R_EB (``ModelInputs._to_S``)."""
        raise NotImplementedError

    def _prepare(
        self, block: AlignedSamples, usable: bool = True, motion: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        """The block's readings with the configured effects applied (``ModelInputs._prepare``)."""
        raise NotImplementedError

    def _bounds(self) -> tuple[float, float]:
        """(force bound N, torque bound N·m) on the parameters' std for convergence (``Convergence._bounds``)."""
        raise NotImplementedError

    def _watch_payload(
        self,
        t_ns: np.ndarray,
        y_f: np.ndarray,
        force_S: np.ndarray,
        torque_S: np.ndarray,
        R_EB: np.ndarray,
        A_f: np.ndarray,
        usable: np.ndarray,
        run_f: StageRun,
        x_before: np.ndarray,
    ) -> None:
        """Follow the force stage's refusal runs for a payload change (``Reopening._watch_payload``)."""
        raise NotImplementedError

    def _torque_reopened(self, t_ns: int) -> None:
        """Say that the torque bias was re-opened (``Reopening._torque_reopened``)."""
        raise NotImplementedError
