"""``batch``: the paper's model fitted by batch least squares over every sample so far.

The estimator is ``estimator.py``, its options ``options.py``; this module registers it.
"""

from hapticlab.core import hookimpl
from hapticlab.plugins.estimators.batch.estimator import BatchEstimator
from hapticlab.plugins.estimators.batch.options import BatchOptions

__all__ = ["BatchEstimator", "BatchOptions"]


@hookimpl
def register_estimators(register):
    register("batch", BatchEstimator)
