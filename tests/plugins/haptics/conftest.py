"""The serial haptic master that the tests of ``serial`` and of the master emulator talk to: ``emulator``, the
emulator on a pty (hapticlab protocol, 8 N), and ``device``, the ``serial`` plugin opened on it (5 N).
test_inverse3.py has its own two, for the Inverse3 protocol."""

from __future__ import annotations

import pytest
from helpers import READ_TIMEOUT_S

from hapticlab.plugins.haptics.serial import SerialHaptic


@pytest.fixture
def emulator(master_emulator):
    with master_emulator("hapticlab", max_force=8.0) as em:
        yield em


@pytest.fixture
def device(emulator):
    dev = SerialHaptic(
        emulator.port, "hapticlab", device_max_force=5.0, read_timeout=READ_TIMEOUT_S, reconnect_interval=0.05
    )
    dev.open()
    yield dev
    dev.close()
