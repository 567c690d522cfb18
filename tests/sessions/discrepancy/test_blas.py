"""numpy's BLAS on one thread for a while, then as before."""

from __future__ import annotations

import numpy as np

from hapticlab.sessions.discrepancy.blas import _openblas, single_threaded_blas


def test_single_threaded_blas_sets_and_restores():
    found = _openblas()
    A = np.arange(12.0).reshape(4, 3)
    with single_threaded_blas():
        if found is not None:
            assert found[1]() == 1
        np.testing.assert_array_equal(A.T @ A, np.einsum("ij,ik->jk", A, A))
    if found is not None:
        before = found[1]()
        with single_threaded_blas():
            pass
        assert found[1]() == before
