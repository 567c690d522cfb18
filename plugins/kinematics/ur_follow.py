"""Teleoperating a UR arm: the flange target over RTDE input registers, to the URScript hapticlab ships.

The arm is moved by a URScript running on its controller,
``urscript/hapticlab_follow.script`` (what to load on the pendant is in its
header and in docs/devices.md): every controller cycle it reads the target
hapticlab writes and ``servoj``-s to it, and stops the arm when no new target
has come for ``WATCHDOG_S``. hapticlab writes the target through ur-rtde's
``RTDEIOInterface``, whose lower range reaches input registers 18–22 (its
control interface's own script keeps 0–17), so the six numbers of a pose go
into three double and three integer registers:

==========================  =====================================================
``input_double_register_18..20``  target TCP position in Base, x y z, m
``input_int_register_18..20``     target TCP rotation vector in Base, rx ry rz, µrad
``input_int_register_21``         the target's sequence number, written last
``output_int_register_21``        (the script's) the sequence number it last applied
==========================  =====================================================

A µrad of rotation is 0.25 µm at the tip of a 25 cm tool: far under the arm's
repeatability. Each register is its own RTDE data package, so the script may
read a target half-written; between two consecutive targets (one controller
period apart, at teleoperation's speed limit) the values differ by a tenth of a
millimetre, and the sequence number, written last, makes the script pick the
whole target up at the next cycle.
"""

from __future__ import annotations

import contextlib
import os
import select
import subprocess
import sys
from importlib import resources
from pathlib import Path

import numpy as np

from hapticlab.core.frames import matrix_from_rotvec, rotvec_from_matrix
from hapticlab.plugins.kinematics.ur_target_writer import POSITION_REGISTERS as POSITION_REGISTERS
from hapticlab.plugins.kinematics.ur_target_writer import RECORD
from hapticlab.plugins.kinematics.ur_target_writer import ROTATION_REGISTERS as ROTATION_REGISTERS
from hapticlab.plugins.kinematics.ur_target_writer import SEQUENCE_REGISTER as SEQUENCE_REGISTER

# POSITION_REGISTERS: input_double_register_N, the target position (m); ROTATION_REGISTERS:
# input_int_register_N, the target rotation vector (µrad); SEQUENCE_REGISTER: input_int_register_N,
# the target's sequence number (0: none yet), and output_int_register_N, the script's echo;
# RECORD: one target on the pipe to the writer process. (They live in the writer's file, which
# runs as a script without hapticlab's packages.)
MICRORAD = 1e-6
WATCHDOG_S = 0.1
"""The script stops the arm when no new sequence number has come for this long, s."""
WRITER_START_TIMEOUT_S = 10.0
"""How long the writer process may take to start and connect, s."""


def script_path() -> Path:
    """The URScript to run on the controller (``hapticlab_follow.script``, shipped with hapticlab)."""
    return Path(str(resources.files("hapticlab.plugins.kinematics") / "urscript" / "hapticlab_follow.script"))


def encode_target(R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> tuple[list[float], list[int]]:
    """The registers' values for a flange target: ([x, y, z] m, [rx, ry, rz] µrad as int32)."""
    rotvec = rotvec_from_matrix(np.asarray(R_BE, dtype=float))
    return [float(v) for v in p_BoEo_B], [round(v / MICRORAD) for v in rotvec]


def decode_target(position: list[float], rotation: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The flange target the registers hold: ``(R_BE (3, 3), p_BoEo_B (3,) m)`` (what the script reads)."""
    return matrix_from_rotvec(np.asarray(rotation, dtype=float) * MICRORAD), np.asarray(position, dtype=float)


class TargetWriter:
    """Writes flange targets to a UR controller's input registers through ur-rtde's RTDEIOInterface, from a
    process of its own (``ur_target_writer.py``: ur-rtde holds the interpreter lock while it writes).

    Args:
        address: the controller's IP address or host name.

    ``send`` hands the target over a pipe and returns; the writer takes the newest when it is free.
    """

    def __init__(self, address: str):
        self.address = address
        self._proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).with_name("ur_target_writer.py")), address],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=False,
        )
        self._pipe = self._proc.stdin.fileno()  # type: ignore[union-attr]  # stdin=PIPE
        ready, _, _ = select.select([self._proc.stdout], [], [], WRITER_START_TIMEOUT_S)  # type: ignore[type-var]  # stdout=PIPE
        line = self._proc.stdout.readline().decode(errors="replace").strip() if ready else ""  # type: ignore[union-attr]  # stdout=PIPE
        if line != "ready":
            self._proc.kill()
            self._proc.wait()
            why = line.removeprefix("error: ") or f"no answer within {WRITER_START_TIMEOUT_S:g} s"
            raise ConnectionError(f"UR controller {address}:30004 (RTDE inputs for teleoperation): {why}")

    def send(self, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None:
        """Hand one target to the writer; ConnectionError when the writer has stopped (saying why)."""
        position, rotation = encode_target(R_BE, p_BoEo_B)
        try:
            os.write(self._pipe, RECORD.pack(*position, *rotation))
        except (BrokenPipeError, OSError):
            self._proc.wait()
            why = self._proc.stdout.read().decode(errors="replace").strip().removeprefix("error: ")  # type: ignore[union-attr]  # stdout=PIPE
            raise ConnectionError(
                f"UR controller {self.address}: the target writer stopped "
                f"(exit status {self._proc.returncode}){': ' + why if why else ''}"
            ) from None

    def close(self) -> None:
        """End the writer (end of file on its pipe); the arm's script stops the arm when targets stop."""
        with contextlib.suppress(OSError):
            self._proc.stdin.close()  # type: ignore[union-attr]  # stdin=PIPE
        try:
            self._proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
