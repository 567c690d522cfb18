"""The reference firmware's protocol logic, built for the host and driven by the ``serial`` plugin over a pty.

``firmware/hapticlab_master/hapticlab_master.ino`` is compiled with the
host's g++ against a stand-in for the Arduino core (``firmware_host/``: Serial
is the process's stdin/stdout, the sensor reads a fixed ADC count, motor PWM
is logged to stderr). That checks the sketch's framing, CRC, handshake,
clamp, NaN guard and watchdog against the plugin; it is not an AVR build
(no Arduino toolchain here), so timing and the hardware section are untested.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
import tty
from pathlib import Path

import numpy as np
import pytest
from helpers import ROOT

from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics import framing
from hapticlab.plugins.haptics.serial import SerialHaptic

SKETCH = ROOT / "firmware" / "hapticlab_master" / "hapticlab_master.ino"
HOST = Path(__file__).resolve().parent / "firmware_host"
GUARD_S = 10.0

ADC_COUNT, ZERO_COUNT, METRES_PER_COUNT = 600, 512, 0.00012  # the stand-in's reading, the sketch's calibration
NEWTONS_AT_FULL_PWM = 3.2


@pytest.fixture(scope="module")
def firmware(tmp_path_factory) -> Path:
    compiler = shutil.which("g++")
    if compiler is None:
        pytest.skip("no g++ to build the sketch for the host")
    binary = tmp_path_factory.mktemp("firmware") / "hapticlab_master"
    subprocess.run(
        [
            compiler,
            "-std=gnu++11",
            "-Wall",
            "-Wextra",
            "-Werror",
            f"-I{HOST}",
            "-x",
            "c++",
            str(SKETCH),
            str(HOST / "host.cpp"),
            "-o",
            str(binary),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return binary


@pytest.fixture
def board(firmware, tmp_path, pty_pair, spawn_process):
    """The sketch running as a process on the master side of a pty: (slave path, PWM log path)."""
    master, slave = pty_pair
    tty.setraw(slave)
    log = tmp_path / "pwm.log"
    with open(log, "w") as stderr:
        spawn_process(
            [str(firmware)],
            "the sketch",
            stdin=master,
            stdout=master,
            stderr=stderr,
            env={**os.environ, "ADC_COUNT": str(ADC_COUNT)},
        )
    return os.ttyname(slave), log


def last_pwm(log: Path) -> tuple[int, int]:
    """(direction pin, duty 0..255) of the sketch's last analogWrite."""
    direction, duty = log.read_text().split("\n")[-2].split()[1:]
    return int(direction), int(duty)


def test_the_sketch_handshakes_reports_its_handle_and_drives_its_motor(board):
    port, log = board
    dev = SerialHaptic(port, device_max_force=5.0, read_timeout=1.0)
    dev.open()
    assert dev.info == "hapticlab protocol v1 device 19249 firmware 1, max 3 N, 1000 Hz" and dev.max_force == 3.0
    dev.send(HapticCommand(1, np.array([0.5, 0.0, 0.0]), True))
    x = np.float32((ADC_COUNT - ZERO_COUNT) * np.float32(METRES_PER_COUNT))
    np.testing.assert_allclose(dev.state().p_DoHo_D, [x, 0.0, 0.0], rtol=1e-6)
    assert last_pwm(log) == (0, int(0.5 / NEWTONS_AT_FULL_PWM * 255 + 0.5))
    dev.send(HapticCommand(2, np.array([-10.0, 0.0, 0.0]), True))  # the plugin clamps to the device's 3 N
    assert last_pwm(log) == (1, int(3.0 / NEWTONS_AT_FULL_PWM * 255 + 0.5)) and dev.status == 0
    dev.send(HapticCommand(3, np.array([np.nan, 0.0, 0.0]), True))
    assert last_pwm(log)[1] == 0
    dev.close()


def test_the_sketch_guards_itself_against_a_host_that_does_not(board):
    port, log = board
    dev = SerialHaptic(port, read_timeout=1.0)
    dev.open()
    reading = dev.link.exchange(np.array([10.0, 0.0, 0.0], np.float32))  # past the plugin's clamp
    assert reading.status & framing.STATUS_CLAMPED and last_pwm(log) == (0, int(3.0 / NEWTONS_AT_FULL_PWM * 255 + 0.5))
    dev.link.exchange(np.array([np.nan, 1.0, 0.0], np.float32))
    assert last_pwm(log)[1] == 0
    dev.port.write(b"\x00\xa5\x5a\x02\x01\x0c" + bytes(14))  # noise, then a FORCE whose CRC is wrong
    deadline = time.monotonic() + GUARD_S
    while dev.port.waiting() < framing.HEADER_SIZE + framing.NAK_FORMAT.size + framing.CRC_SIZE:
        assert time.monotonic() < deadline
        time.sleep(0.002)
    frames = framing.FrameDecoder().feed(dev.port.read(4096, 0.0))
    assert [(f.kind, f.payload[1]) for f in frames] == [(framing.NAK, framing.NAK_CRC)]
    dev.send(HapticCommand(4, np.array([0.2, 0.0, 0.0]), True))  # and it goes on
    assert dev.errors_in_row == 0 and last_pwm(log)[1] == int(0.2 / NEWTONS_AT_FULL_PWM * 255 + 0.5)
    dev.close()


def test_the_sketchs_watchdog_zeroes_the_motor_when_the_host_goes_quiet(board):
    port, log = board
    dev = SerialHaptic(port, watchdog=0.05, read_timeout=1.0)
    dev.open()
    dev.send(HapticCommand(1, np.array([1.0, 0.0, 0.0]), True))
    assert last_pwm(log)[1] > 0
    deadline = time.monotonic() + GUARD_S
    while last_pwm(log)[1] != 0:  # the host sends nothing: the sketch has to act alone
        assert time.monotonic() < deadline, "the watchdog never zeroed the motor"
        time.sleep(0.01)
    dev.send(HapticCommand(2, np.array([0.0, 0.0, 0.0]), True))
    assert dev.status == framing.STATUS_WATCHDOG
    dev.close()
