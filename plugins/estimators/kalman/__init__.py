"""``kalman``: the paper's cascade as Kalman filters, with drifting biases.

The estimator is ``estimator.py`` (put together from ``inputs.py``, ``convergence.py``, ``reopen.py`` and
``warm_start.py``), its options ``options.py``; one stage's filter is ``stage.py`` with its compiled twin
``stage_kernel.py``, the whole cascade compiled ``cascade_kernel.py``. This module registers it.
"""

from hapticlab.core import hookimpl
from hapticlab.plugins.estimators.kalman.convergence import IDENTIFICATION_EVENTS
from hapticlab.plugins.estimators.kalman.estimator import KalmanEstimator
from hapticlab.plugins.estimators.kalman.options import EFFECT_OPTIONS, KalmanOptions, mount_matrix

__all__ = ["EFFECT_OPTIONS", "IDENTIFICATION_EVENTS", "KalmanEstimator", "KalmanOptions", "mount_matrix"]


@hookimpl
def register_estimators(register):
    register("kalman", KalmanEstimator)
