"""Both estimators' compiled kernels refuse the same bad samples (NaN, inf, an R_EB that is not a rotation) and
keep their state as if those samples had never arrived; kalman's numpy reference does the same, to rounding
(``kalman_tolerance``, tests/helpers.py). What every estimator does with such samples: test_poisoning.py."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import GAMMA, KEYS, kalman_tolerance, run_blocks, same

from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.plugins.estimators.rls import RLSEstimator


@pytest.mark.parametrize("size", [1, 7])
def test_kernels_refuse_the_same_samples_and_keep_the_state(sim, size, numpy_reference):
    block = sim.subset(np.arange(1400))  # a copy (a slice is a view): the module's tour must stay clean
    block.force_S[700, 1] = np.nan
    block.torque_S[703] = np.inf
    block.R_EB[1100] *= 2.0  # not a rotation
    bad = np.array([700, 703, 1100])
    clean = block.subset(np.setdiff1d(np.arange(len(block)), bad))
    for make in (RLSEstimator, KalmanEstimator, lambda **kw: KalmanEstimator(**GAMMA, **kw)):
        fast, without = make(kernel="numba"), make(kernel="numba")
        b = run_blocks(fast, block, size)
        assert fast.refused_samples == 3
        assert np.isnan(b["contact_force_S"][bad]).all() and not b["contact"][bad].any()
        c = run_blocks(without, clean, size)  # as if the bad samples had never arrived
        for key in KEYS:
            assert np.array_equal(np.delete(b[key], bad, axis=0), c[key]), (make, key)
        assert fast.params() == without.params() and fast.cov_diag() == without.cov_diag()
        if make is not RLSEstimator:  # and the numpy reference does the same, to rounding
            ref = make(kernel="numpy")
            a = run_blocks(ref, block, size)
            assert ref.refused_samples == 3
            for key in KEYS:
                assert same(a[key], b[key], key, kalman_tolerance({} if make is KalmanEstimator else GAMMA)), key
