"""The simulated tours the estimators' compiled kernels are held to their numpy references on (tests of rls/,
kalman/ and test_kernels.py here): module-scoped, so a test that spoils samples works on a copy."""

from __future__ import annotations

import pytest
from helpers import kernel_tour


@pytest.fixture(scope="module")
def sim():
    return kernel_tour(3.0)


@pytest.fixture(scope="module")
def sim6():
    """6 s: the kalman torque stage converges after ~4 s of this tour."""
    return kernel_tour(6.0)
