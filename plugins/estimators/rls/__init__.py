"""``rls``: the paper's cascaded recursive least squares (Algorithm 1).

The estimator is ``estimator.py``, its options ``options.py``; this module registers it.
"""

from hapticlab.core import hookimpl
from hapticlab.plugins.estimators.rls.estimator import RLSEstimator
from hapticlab.plugins.estimators.rls.options import RLSOptions

__all__ = ["RLSEstimator", "RLSOptions"]


@hookimpl
def register_estimators(register):
    register("rls", RLSEstimator)
