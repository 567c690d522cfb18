"""The RTDE wire (Universal Robots, "Real-Time Data Exchange (RTDE) Guide", protocol version 2).

TCP port 30004; every package is ``uint16 size, uint8 type`` then the payload,
big-endian, ``size`` counting the 3 header bytes:

* ``V`` request protocol version (``uint16``) → ``uint8 accepted``.
* ``v`` get controller version → ``uint32 major, minor, bugfix, build``
  (5.x for the e-Series models, 3.x for CB3: ur-rtde picks 500 or 125 Hz from the major).
* ``M`` text message, both ways: ``uint8 length, message, uint8 length, source,
  uint8 warning level`` (0 exception, 1 error, 2 warning, 3 info).
* ``O`` control package setup outputs: ``double frequency`` and comma-separated
  variable names → ``uint8 recipe id`` and comma-separated types, ``NOT_FOUND``
  for a name the controller does not know (then the recipe id is 0: the setup
  failed). An empty last name (a trailing comma, as ur-rtde writes) is ignored.
* ``I`` control package setup inputs: comma-separated names → ``uint8 recipe
  id`` and types, ``NOT_FOUND`` for an unknown name and ``IN_USE`` for a field
  another client's recipe already writes (recipe id 0 then).
* ``S`` start and ``P`` pause the client's data packages → ``uint8 accepted``.
* ``U`` data package: controller → client ``uint8 recipe id`` then the
  recipe's fields, at its frequency while started; client → controller an input
  recipe's values.

The field names and their types are the guide's output and input tables
(:data:`OUTPUT_TYPES`, :data:`INPUT_TYPES`); :data:`TYPE_FORMATS` gives each
type's ``struct`` format.
"""

from __future__ import annotations

import struct
from typing import Any

RTDE_PORT = 30004
PROTOCOL_VERSION = 2
HEADER = struct.Struct(">HB")
"""Every RTDE package starts with ``uint16 size`` (header included) and ``uint8 type``."""

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

EXCEPTION, ERROR, WARNING, INFO = 0, 1, 2, 3
"""Text message warning levels."""

TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
"""struct format of each RTDE type (big-endian)."""


def _output_types() -> dict[str, str]:
    """Every output name the emulator knows, with its RTDE type (the RTDE guide's output table)."""
    types = {"timestamp": "DOUBLE"}
    for name in (
        "target_q",
        "target_qd",
        "target_qdd",
        "target_current",
        "target_moment",
        "actual_q",
        "actual_qd",
        "actual_qdd",
        "actual_current",
        "actual_current_as_torque",
        "joint_control_output",
        "actual_TCP_pose",
        "actual_TCP_speed",
        "actual_TCP_force",
        "target_TCP_pose",
        "target_TCP_speed",
        "joint_temperatures",
        "actual_joint_voltage",
        "ft_raw_wrench",
        "payload_inertia",
    ):
        types[name] = "VECTOR6D"
    for name in (
        "actual_execution_time",
        "speed_scaling",
        "target_speed_fraction",
        "actual_momentum",
        "actual_main_voltage",
        "actual_robot_voltage",
        "actual_robot_current",
        "standard_analog_input0",
        "standard_analog_input1",
        "standard_analog_output0",
        "standard_analog_output1",
        "io_current",
        "euromap67_24V_voltage",
        "euromap67_24V_current",
        "tool_analog_input0",
        "tool_analog_input1",
        "tool_output_current",
        "tool_temperature",
        "tcp_force_scalar",
        "speed_scaling_combined",
        "payload",
    ):
        types[name] = "DOUBLE"
    for name in ("actual_tool_accelerometer", "elbow_position", "elbow_velocity", "payload_cog"):
        types[name] = "VECTOR3D"
    for name in ("actual_digital_input_bits", "actual_digital_output_bits"):
        types[name] = "UINT64"
    for name in (
        "runtime_state",
        "robot_status_bits",
        "safety_status_bits",
        "analog_io_types",
        "euromap67_input_bits",
        "euromap67_output_bits",
        "tool_mode",
        "tool_analog_input_types",
        "output_bit_registers0_to_31",
        "output_bit_registers32_to_63",
        "input_bit_registers0_to_31",
        "input_bit_registers32_to_63",
        "script_control_line",
    ):
        types[name] = "UINT32"
    for name in ("robot_mode", "safety_mode", "safety_status", "tool_output_voltage"):
        types[name] = "INT32"
    types["joint_mode"] = "VECTOR6INT32"
    for i in range(48):
        types[f"output_int_register_{i}"] = types[f"input_int_register_{i}"] = "INT32"
        types[f"output_double_register_{i}"] = types[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        types[f"output_bit_register_{i}"] = types[f"input_bit_register_{i}"] = "BOOL"
    return types


def _input_types() -> dict[str, str]:
    """Every input name the emulator accepts, with its RTDE type (the RTDE guide's input table)."""
    types = {
        "speed_slider_mask": "UINT32",
        "speed_slider_fraction": "DOUBLE",
        "standard_digital_output_mask": "UINT8",
        "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8",
        "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8",
        "tool_digital_output": "UINT8",
        "standard_analog_output_mask": "UINT8",
        "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE",
        "standard_analog_output_1": "DOUBLE",
        "input_bit_registers0_to_31": "UINT32",
        "input_bit_registers32_to_63": "UINT32",
        "external_force_torque": "VECTOR6D",
        "ft_rtde_input_enable": "BOOL",
    }
    for i in range(48):
        types[f"input_int_register_{i}"] = "INT32"
        types[f"input_double_register_{i}"] = "DOUBLE"
    for i in range(64, 128):
        types[f"input_bit_register_{i}"] = "BOOL"
    return types


OUTPUT_TYPES = _output_types()
INPUT_TYPES = _input_types()


def zero(rtde_type: str) -> Any:
    """The value of an RTDE type that the controller does not model: 0 (False, or a tuple of zeros)."""
    fmt = TYPE_FORMATS[rtde_type]
    zero = False if fmt == "?" else 0.0 if fmt.endswith("d") else 0
    return (zero,) * int(fmt[0]) if fmt[0].isdigit() else zero


def pack_text_message(message: str, source: str = "hapticlab emulator", level: int = INFO) -> bytes:
    """A protocol-2 text message package (controller → client or client → controller)."""
    body = message.encode()[:255]
    src = source.encode()[:255]
    payload = bytes([len(body)]) + body + bytes([len(src)]) + src + bytes([level])
    return HEADER.pack(HEADER.size + len(payload), TEXT_MESSAGE) + payload


def package(kind: int, payload: bytes = b"") -> bytes:
    """A package of type ``kind`` (``ord("U")``, ...) with its header."""
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


def names(raw: bytes) -> list[str]:
    """Comma-separated variable names; an empty last name (a trailing comma) is ignored."""
    names = raw.decode(errors="replace").split(",")
    if names and names[-1] == "":
        names.pop()
    return names


def width(rtde_type: str) -> int:
    """How many values a field of an RTDE type holds (6 for a VECTOR6D)."""
    fmt = TYPE_FORMATS[rtde_type]
    return int(fmt[0]) if fmt[0].isdigit() else 1


def unpack_text_message(payload: bytes) -> str:
    """The message of a text message package's payload."""
    n = payload[0] if payload else 0
    return payload[1 : 1 + n].decode(errors="replace")
