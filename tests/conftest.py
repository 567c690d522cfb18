"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers import REAL_DATA


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The folder of real recordings; tests using it skip when it is absent."""
    if not REAL_DATA.is_dir():
        pytest.skip("../shared/data/real is not present")
    return REAL_DATA
