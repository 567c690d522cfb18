"""Teleoperating a UR arm: the registers the shipped URScript reads, written by ur-rtde from a child
process, and the emulated controller running that script's logic (follow, echo, watchdog)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hapticlab.plugins.kinematics.ur_emulator import UREmulator
from hapticlab.plugins.kinematics.ur_follow import (
    MICRORAD,
    SEQUENCE_REGISTER,
    TargetWriter,
    decode_target,
    encode_target,
    script_path,
)
from hapticlab.plugins.simworld import SimWorld


def test_a_target_survives_the_registers_to_a_micro_radian():
    R = Rotation.from_rotvec([0.3, -2.9, 0.4]).as_matrix()
    p = np.array([0.41, -0.123456789, 0.35])
    position, rotation = encode_target(R, p)
    assert all(isinstance(v, int) for v in rotation)
    R_back, p_back = decode_target(position, rotation)
    assert np.array_equal(p_back, p)
    assert np.linalg.norm(Rotation.from_matrix(R_back.T @ R).as_rotvec()) < 2 * MICRORAD


def test_the_shipped_script_reads_the_registers_the_writer_writes():
    text = script_path().read_text()
    for register in (
        "read_input_float_register(18)",
        "read_input_float_register(20)",
        "read_input_integer_register(18)",
        "read_input_integer_register(20)",
        f"read_input_integer_register({SEQUENCE_REGISTER})",
        f"write_output_integer_register({SEQUENCE_REGISTER}",
        "servoj(",
        "stopj(",
    ):
        assert register in text


def until(condition, what: str, timeout: float = 10.0) -> None:
    """Wait for ``condition()`` (a deadline against hanging, naming what was awaited; not a timing assertion)."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"{what}: not within {timeout:g} s"
        time.sleep(0.005)


def servo_world() -> SimWorld:
    return SimWorld.from_config({"seed": 2, "motion": {"script": "servo"}})


def test_the_emulated_arm_follows_written_targets_and_stops_when_they_stop(child_processes):
    world = servo_world()
    R_0, p_0 = world.motion.target
    with UREmulator(world, address="127.0.0.86") as arm:
        assert arm.follows
        writer = TargetWriter("127.0.0.86")  # ur-rtde in a child process: it may share a process with the emulator
        try:
            t_end = time.monotonic() + 0.6
            while time.monotonic() < t_end:  # 2 cm down, sent at 125 Hz
                writer.send(R_0, p_0 - [0.0, 0.0, 0.02])
                time.sleep(0.008)
            until(lambda: arm.watchdog_stops == 1, "the watchdog's stop once the targets stopped")
            reached = world.pose((time.monotonic_ns() - arm.t0_ns) / 1e9)[1][0]
            assert np.isclose(reached[2], p_0[2] - 0.02, atol=1e-3)
            assert arm.targets_applied >= 30
            assert arm.watchdog_stops == 1  # the targets stopped: the arm stopped (where it already was)
            # one far target, then silence: the script's watchdog stops the arm on its way
            writer.send(R_0, p_0 - [0.0, 0.0, 0.12])
            time.sleep(0.6)  # the watchdog's 100 ms, then the arm's stop
            t = (time.monotonic_ns() - arm.t0_ns) / 1e9
            stopped = world.pose(t)[1][0]
            assert p_0[2] - 0.09 < stopped[2] < p_0[2] - 0.021  # moved towards it, stopped well short
            assert np.isclose(world.pose(t + 0.2)[1][0][2], stopped[2], atol=1e-4)  # and stays
            assert arm.watchdog_stops == 2
        finally:
            writer.close()


def test_the_writer_names_the_controller_it_cannot_reach(child_processes):
    with pytest.raises(ConnectionError, match=r"UR controller 127.0.0.87:30004 \(RTDE inputs for teleoperation\)"):
        TargetWriter("127.0.0.87")
