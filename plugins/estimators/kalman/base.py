"""What every part of the ``kalman`` estimator shares: its attributes, and the small methods they all call.

:class:`KalmanEstimator` is put together from parts, one file each (``inputs.py``, ``convergence.py``,
``reopen.py``, ``warm_start.py``); each part derives from :class:`KalmanBase`, which names the state
they read and write (set once by ``KalmanEstimator.__init__``).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.types import Event
from hapticlab.plugins.estimators.kalman.options import KalmanOptions
from hapticlab.plugins.estimators.kalman.payload import PayloadWatch
from hapticlab.plugins.estimators.kalman.stage import KalmanStage
from hapticlab.plugins.estimators.kalman.state_layout import ADAPT_TILT_TORQUE


class KalmanBase:
    """The attributes the estimator's parts share, and the methods more than one of them calls."""

    force: KalmanStage
    torque: KalmanStage
    options: KalmanOptions
    kernel: str
    method: str | None
    convergence: str
    identifies: bool
    mount_rotation: bool
    mount_configured: bool
    bias_rate: bool
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
    converged_force_std_option: float | None
    converged_torque_std_option: float | None
    torque_reopen_s: float
    payload_changes: int
    events: list[Event]
    _adapt: np.ndarray
    _information: dict[str, np.ndarray]
    _unidentified: dict[str, tuple[int, ...]]
    _last_t_ns: int | None
    _cog_known: bool
    _mass_known: bool
    _payload: PayloadWatch
    _L6: np.ndarray

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
