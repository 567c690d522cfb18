"""Shared fixtures, and the test run's two rules.

* Only the built-in plugins: ``HAPTICLAB_LOAD_PLUGINS`` is set to the empty
  string before any registry is built, so a third-party hapticlab plugin
  installed in the same environment cannot change what the tests see.
* Under ``CI=true`` the real recordings (``../shared/data/real``) must be
  there: a test that needs them fails instead of skipping.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from helpers import REAL_DATA

os.environ["HAPTICLAB_LOAD_PLUGINS"] = ""  # built-ins only (entry points: none)


@pytest.fixture(scope="session")
def real_data() -> Path:
    """The folder of real recordings; absent, tests using it skip (fail under CI=true)."""
    if not REAL_DATA.is_dir():
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(f"{REAL_DATA} is missing: under CI=true the real-data tests must run")
        pytest.skip("../shared/data/real is not present")
    return REAL_DATA
