"""A protocol-faithful Universal Robots controller's RTDE interface on loopback, driven by the simulated world.

What it speaks (Universal Robots, "Real-Time Data Exchange (RTDE) Guide",
protocol version 2; TCP port 30004, every package ``uint16 size, uint8 type``
then the payload, big-endian, ``size`` counting the 3 header bytes):

* ``V`` request protocol version (``uint16``) → ``uint8 accepted`` (only 2 is accepted).
* ``v`` get controller version → ``uint32 major, minor, bugfix, build``
  (5.x for the e-Series models, 3.x for CB3: ur-rtde picks 500 or 125 Hz from the major).
* ``M`` text message, both ways: ``uint8 length, message, uint8 length, source,
  uint8 warning level`` (0 exception, 1 error, 2 warning, 3 info). The emulator
  sends one when it refuses something; messages a client sends are kept in
  :attr:`UREmulator.messages`.
* ``O`` control package setup outputs: ``double frequency`` and comma-separated
  variable names → ``uint8 recipe id`` and comma-separated types, ``NOT_FOUND``
  for a name it does not know (then the recipe id is 0: the setup failed). An
  empty last name (a trailing comma, as ur-rtde writes) is ignored. The
  frequency must be within (0, 500] Hz on an e-Series, (0, 125] on a CB3.
* ``I`` control package setup inputs: comma-separated names → ``uint8 recipe
  id`` and types, ``NOT_FOUND`` for an unknown name and ``IN_USE`` for a field
  another client's recipe already writes (recipe id 0 then).
* ``S`` start and ``P`` pause the client's data packages → ``uint8 accepted``.
* ``U`` data package: controller → client ``uint8 recipe id`` then the
  recipe's fields, at its frequency while started; client → controller an input
  recipe's values, which the emulator keeps (:meth:`UREmulator.inputs`).

``RTDEReceiveInterface`` (ur-rtde 1.6) needs exactly this on port 30004 and no
other port (the dashboard server on 29999 and the URScript ports 30001–30003
are only for ``RTDEControlInterface``): ``V``, ``v``, ``O``, ``S``, then ``U``
packages, and ``P`` when it disconnects. ``RTDEIOInterface`` adds ``I``
recipes and ``U`` packages towards the controller.

The robot: the controller's cycle is 2 ms (e-Series, 500 Hz) or 8 ms (CB3,
125 Hz) and ``timestamp`` counts cycles in seconds since the emulator started.
At a cycle where a package is due, the world's flange pose at that time gives
the joints by inverse kinematics on the continuous branch (the solution
nearest the previous q, ``ur_arm.inverse_nearest``); ``actual_q`` is that
plus the encoders' jitter (``encoder_noise``, a function of the world's seed
and the time), ``actual_TCP_pose`` (position and rotation vector, the TCP
being the flange) the forward kinematics of ``actual_q`` (with no jitter: the
world's pose itself), ``actual_qd`` the difference of consecutive
``actual_q`` over their time. ``target_q``/``target_qd``/
``target_TCP_pose`` equal the actual values, ``robot_mode`` is 7 (running),
``safety_mode`` 1 (normal), ``runtime_state`` 1 (stopped: no program), input
registers read back what clients wrote; every other known output is a
constant of its type (0).

**Following** (a world whose motion is ``servo``, ``SimWorld.live``): the
controller runs ``hapticlab_follow.script`` as the real one would
(``ur_follow.py``): at each cycle a new sequence number in
``input_int_register_21`` sends the world's robot to the target in registers
18–20 (``servo_cp``), ``output_int_register_21`` echoes the number applied,
``runtime_state`` is 2 (playing), and with no new number for ``WATCHDOG_S`` the
arm stops where it is. Packages go out in bursts about once a millisecond,
every one whose cycle has come (none is dropped when the scheduler is late).

Run it as ``hapticlab emulate ur --address 127.0.0.x`` (:func:`add_arguments`,
:func:`run`) or from Python::

    with UREmulator(world, address="127.0.0.31", model="ur5e") as emu:
        ...  # a client in another process: ur-rtde's RTDEReceiveInterface("127.0.0.31")
        emu.inputs()["input_double_register_18"]

ur-rtde's constructors hold the GIL while they wait for the controller's
answers, so a ur-rtde client in the emulator's own process waits forever: run
the two in different processes (the emulator's threads need the GIL to answer).
"""

from __future__ import annotations

import argparse
import math
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.frames import matrix_from_quat_wxyz, quat_from_rotvec, quat_wxyz_from_matrix, rotvec_from_quat
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins.kinematics.sim import ENCODER_STREAM
from hapticlab.plugins.kinematics.ur_arm import UR_DH, URArm
from hapticlab.plugins.kinematics.ur_follow import (
    POSITION_REGISTERS,
    ROTATION_REGISTERS,
    SEQUENCE_REGISTER,
    WATCHDOG_S,
    decode_target,
)
from hapticlab.plugins.serving import serve_until_stopped
from hapticlab.plugins.simworld.physics import SimWorld, gaussian_noise

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

CONTROLLER_VERSIONS = {False: (5, 15, 0, 0), True: (3, 15, 8, 0)}
"""Controller version reported: e-Series (False) or CB3 (True)."""
CYCLE_HZ = {False: 500.0, True: 125.0}
"""Controller cycle rate (the highest RTDE frequency), Hz: e-Series (False) or CB3 (True)."""

ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
RUNTIME_STATE_STOPPED = 1
RUNTIME_STATE_PLAYING = 2


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


def _zero(rtde_type: str) -> Any:
    fmt = TYPE_FORMATS[rtde_type]
    zero = False if fmt == "?" else 0.0 if fmt.endswith("d") else 0
    return (zero,) * int(fmt[0]) if fmt[0].isdigit() else zero


def pack_text_message(message: str, source: str = "hapticlab emulator", level: int = INFO) -> bytes:
    """A protocol-2 text message package (controller → client or client → controller)."""
    body = message.encode()[:255]
    src = source.encode()[:255]
    payload = bytes([len(body)]) + body + bytes([len(src)]) + src + bytes([level])
    return HEADER.pack(HEADER.size + len(payload), TEXT_MESSAGE) + payload


def _package(kind: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


@dataclass
class _OutputRecipe:
    recipe_id: int
    names: list[str]
    packer: struct.Struct
    every: float
    """Controller cycles per package (cycle rate / frequency)."""
    next_cycle: float = 0.0


@dataclass
class _Client:
    sock: socket.socket
    peer: str
    outputs: dict[int, _OutputRecipe] = field(default_factory=dict)
    inputs: dict[int, tuple[list[str], struct.Struct]] = field(default_factory=dict)
    streaming: bool = False
    protocol: int = 1
    send_lock: threading.Lock = field(default_factory=threading.Lock)

    def send(self, data: bytes) -> bool:
        """Send a whole package; False when the client has gone."""
        try:
            with self.send_lock:
                self.sock.sendall(data)
            return True
        except OSError:
            return False


class UREmulator:
    """A UR controller's RTDE server (port 30004) on a loopback address, fed by a SimWorld.

    Parameters
    ----------
    world : the simulated world whose flange pose (``world.pose(t)``, Base frame) the arm follows.
    address : IPv4 address to listen on (a distinct 127.0.0.x per emulator: ur-rtde always uses port 30004).
    model : a key of ``ur_arm.UR_DH``; ``ur3``/``ur5``/``ur10`` are CB3 (3.x controller, 125 Hz cycle),
        the others e-Series (5.x, 500 Hz).
    port : TCP port (30004 for ur-rtde; 0 picks a free one, for raw-protocol clients).
    encoder_noise : standard deviation of each joint's reading around the true joint angle, rad. A real
        arm's encoders jitter, so its reported pose is never bit-identical from one cycle to the next (the
        session's frozen-pose watch relies on that); ``actual_TCP_pose`` is then the forward kinematics of
        the jittered joints, as the controller computes it. 0: the world's exact pose.
    tcp_offset : the TCP set in the robot's installation, as the controller takes it: (6,) position
        p_EoTo_E (m) and rotation vector of R_ET (rad) of the TCP T in the flange E. ``actual_TCP_pose`` is
        then T's pose, not the flange's (what a lab must avoid: hapticlab needs the flange).
    stalls : windows ``(start, duration)`` of world time, s, in which the controller sends no data package
        while every connection stays open (a stalled stream: a busy controller, a switch holding frames);
        the packages due then are never sent (counted in :attr:`packages_stalled`), and the stream resumes
        at the current cycle, so a client sees the timestamp jump.
    """

    def __init__(
        self,
        world: SimWorld,
        address: str = "127.0.0.1",
        model: str = "ur5e",
        port: int = RTDE_PORT,
        encoder_noise: float = 1e-7,
        tcp_offset: tuple[float, ...] = (0.0,) * 6,
        stalls: tuple[tuple[float, float], ...] | list[tuple[float, float]] = (),
    ):
        if model not in UR_DH:
            raise ValueError(f"model: unknown UR model {model!r}; known: {', '.join(UR_DH)}")
        self.world = world
        self.address = address
        self.port = port
        self.arm = URArm(model)
        self.model = model
        self.cb3 = self.arm.cb3
        self.cycle_hz = CYCLE_HZ[self.cb3]
        self.controller_version = CONTROLLER_VERSIONS[self.cb3]
        q0 = self.arm.inverse_nearest(*[x[0] for x in world.pose(0.0)])
        if q0 is None:
            p = world.pose(0.0)[1][0]
            raise ValueError(
                f"model: a {model} cannot reach the world's flange position "
                f"{np.round(p, 3).tolist()} m at t = 0; give the world's motion a p_BoEo_B within reach"
            )
        self._q, self._q_reported, self._q_t = q0, q0, 0.0
        if not 0 <= encoder_noise <= 1e-3:
            raise ValueError(f"encoder_noise: must be within [0, 1e-3] rad, got {encoder_noise!r}")
        self.encoder_noise = float(encoder_noise)
        tcp = np.asarray(tcp_offset, dtype=float)
        if tcp.shape != (6,) or not np.all(np.isfinite(tcp)):
            raise ValueError(f"tcp_offset: six numbers (x, y, z in m, rotation vector in rad), got {tcp_offset!r}")
        self.p_EoTo_E, self.R_ET = tcp[:3], matrix_from_quat_wxyz(quat_from_rotvec(tcp[3:])[None])[0]
        self.stalls = tuple((float(start), float(duration)) for start, duration in stalls)
        for start, duration in self.stalls:
            if not (start >= 0 and duration > 0 and math.isfinite(start)):
                raise ValueError(f"stall: start must be >= 0 s and duration > 0 s, got {start!r}, {duration!r}")
        self.packages_stalled = 0
        """Data packages not sent because they fell in a stall."""
        self._noise_key = int(
            np.random.SeedSequence(world.seed, spawn_key=(ENCODER_STREAM,)).generate_state(1, np.uint64)[0]
        )
        self._qd = np.zeros(6)
        self._unreachable_reported = False
        self._inputs: dict[str, Any] = {}
        self._input_owner: dict[str, _Client] = {}
        self.messages: list[str] = []
        """Text messages clients sent, oldest first."""
        self.packages_sent = 0
        """Data packages sent to clients since start."""
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._server: socket.socket | None = None
        self.t0_ns: int | None = None
        """The controller's start (``timestamp`` 0, the world's time 0) on the monotonic clock, ns."""
        self._cycle = 0
        self.follows = world.live
        """The controller runs the follow script: the world's robot goes to the targets written to the registers."""
        self.targets_applied = 0
        """Targets the follow script took from the registers."""
        self.watchdog_stops = 0
        """Times the follow script stopped the arm because targets stopped coming."""
        self._sequence_applied = 0
        self._sequence_cycle = -1  # the cycle the last new sequence number came at
        self._stopped = True

    # ------------------------------------------------------------------ life cycle

    def start(self, t0_ns: int | None = None) -> "UREmulator":
        """Listen, and start the controller clock; a second call does nothing.

        ``t0_ns`` is the controller's ``timestamp`` 0 (the world's time 0) on the
        monotonic clock (``time.monotonic_ns``), e.g. another emulator's start so
        both follow one world time; None: now.
        """
        if self._server is not None:
            return self
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((self.address, self.port))
        server.listen(8)
        server.settimeout(0.1)  # the accept loop looks at the stop flag this often
        self.port = server.getsockname()[1]
        self._server = server
        self._stop.clear()
        self.t0_ns = time.monotonic_ns() if t0_ns is None else int(t0_ns)
        for target in (self._accept_loop, self._controller_loop):
            thread = threading.Thread(target=target, name=f"ur-emulator {target.__name__}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def stop(self) -> None:
        """Close every connection and the listening socket (a client sees the controller gone)."""
        self._stop.set()
        if self._server is not None:
            self._server.close()
            self._server = None
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            _close(client.sock)
        for thread in self._threads:
            thread.join(timeout=2.0)
        self._threads.clear()

    def __enter__(self) -> "UREmulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def inputs(self) -> dict[str, Any]:
        """The input fields clients have written (register name → last value)."""
        with self._lock:
            return dict(self._inputs)

    @property
    def clients(self) -> int:
        """Clients connected now."""
        with self._lock:
            return len(self._clients)

    # ------------------------------------------------------------------ the robot

    def state(self, cycle: int) -> dict[str, Any]:
        """The controller's outputs at ``cycle`` (cycles are ``1/cycle_hz`` s apart from start).

        Called in cycle order; q follows the continuous IK branch from the previous call.
        """
        t = cycle / self.cycle_hz
        R_BE, p_BoEo_B = (x[0] for x in self.world.pose(t))
        q = self.arm.inverse_nearest(R_BE, p_BoEo_B, self._q)
        if q is None:  # out of reach: hold the joints, say so once
            q = self._q
            if not self._unreachable_reported:
                self._unreachable_reported = True
                self._broadcast(
                    pack_text_message(
                        f"flange pose {np.round(p_BoEo_B, 3).tolist()} m at t = {t:.3f} s "
                        f"is out of the {self.model}'s reach; joints held",
                        level=WARNING,
                    )
                )
        self._q = q  # the continuous branch follows the true joints
        if self.encoder_noise > 0:  # the encoders' reading, and the controller's FK of it
            t_ns = np.array([round(t * 1e9)], dtype=np.int64)
            q = q + self.encoder_noise * gaussian_noise(self._noise_key, t_ns, 6)[0]
            R_BE, p_BoEo_B = self.arm.forward(q)
        if t > self._q_t:
            self._qd = (q - self._q_reported) / (t - self._q_t)
        self._q_reported, self._q_t = q, t
        p_BoEo_B, R_BE = p_BoEo_B + R_BE @ self.p_EoTo_E, R_BE @ self.R_ET  # the TCP's pose (E's when no offset)
        pose = tuple(np.concatenate([p_BoEo_B, rotvec_from_quat(quat_wxyz_from_matrix(R_BE))]).tolist())
        q_t, qd_t = tuple(q.tolist()), tuple(self._qd.tolist())
        return {
            "timestamp": t,
            "actual_q": q_t,
            "actual_qd": qd_t,
            "target_q": q_t,
            "target_qd": qd_t,
            "actual_TCP_pose": pose,
            "target_TCP_pose": pose,
            "robot_mode": ROBOT_MODE_RUNNING,
            "safety_mode": SAFETY_MODE_NORMAL,
            "safety_status": SAFETY_MODE_NORMAL,
            "runtime_state": RUNTIME_STATE_PLAYING if self.follows else RUNTIME_STATE_STOPPED,
            f"output_int_register_{SEQUENCE_REGISTER}": self._sequence_applied,
            "speed_scaling": 1.0,
            "target_speed_fraction": 1.0,
            "speed_scaling_combined": 1.0,
            "joint_mode": (255,) * 6,
        }

    def _follow(self, cycle: int) -> None:
        """The follow script's cycle: a new target in the registers goes to the world's robot; none for
        ``WATCHDOG_S`` stops it where it is."""
        with self._lock:
            inputs = dict(self._inputs)
        t = cycle / self.cycle_hz
        sequence = int(inputs.get(f"input_int_register_{SEQUENCE_REGISTER}", 0))
        if sequence not in (0, self._sequence_applied):
            R_BE, p_BoEo_B = decode_target(
                [inputs.get(f"input_double_register_{r}", 0.0) for r in POSITION_REGISTERS],
                [inputs.get(f"input_int_register_{r}", 0) for r in ROTATION_REGISTERS],
            )
            try:
                self.world.servo_cp(t, R_BE, p_BoEo_B)
            except ValueError as exc:  # a non-finite target: the script's get_inverse_kin would fail; keep the last
                self._broadcast(pack_text_message(f"hapticlab_follow: target refused: {exc}", level=WARNING))
                return
            self._sequence_applied, self._sequence_cycle, self._stopped = sequence, cycle, False
            self.targets_applied += 1
        elif not self._stopped and (cycle - self._sequence_cycle) / self.cycle_hz > WATCHDOG_S:
            R_BE, p_BoEo_B = (x[0] for x in self.world.pose(t))  # stopj: stop where it is
            self.world.servo_cp(t, R_BE, p_BoEo_B)
            self._stopped = True
            self.watchdog_stops += 1
            self._broadcast(pack_text_message("hapticlab_follow: no target for 100 ms, stopped", level=INFO))

    def _controller_loop(self) -> None:
        """Every cycle whose time has come: send the packages due (bursts about once a millisecond)."""
        while not self._stop.is_set():
            due = math.floor((time.monotonic_ns() - self.t0_ns) * self.cycle_hz / 1e9)
            while self._cycle <= due and not self._stop.is_set():
                if self.follows:
                    self._follow(self._cycle)
                self._serve_cycle(self._cycle)
                self._cycle += 1
            self._stop.wait(0.001)

    def _serve_cycle(self, cycle: int) -> None:
        with self._lock:
            due = [
                (client, recipe)
                for client in self._clients
                if client.streaming
                for recipe in client.outputs.values()
                if recipe.next_cycle <= cycle
            ]
            inputs = dict(self._inputs)
        if not due:
            return
        t = cycle / self.cycle_hz
        if any(start <= t < start + duration for start, duration in self.stalls):  # stalled: nothing goes out
            for client, recipe in due:
                recipe.next_cycle += recipe.every
                self.packages_stalled += 1
            return
        values = self.state(cycle)
        for client, recipe in due:
            recipe.next_cycle += recipe.every
            row = []
            for name in recipe.names:
                value = values[name] if name in values else inputs.get(name, _zero(OUTPUT_TYPES[name]))
                row.extend(value if isinstance(value, tuple) else (value,))
            if client.send(_package(DATA_PACKAGE, bytes([recipe.recipe_id]) + recipe.packer.pack(*row))):
                self.packages_sent += 1

    def _broadcast(self, data: bytes) -> None:
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            client.send(data)

    # ------------------------------------------------------------------ the protocol

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                sock, peer = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setblocking(True)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, f"{peer[0]}:{peer[1]}")
            with self._lock:
                self._clients.append(client)
            threading.Thread(
                target=self._client_loop, args=(client,), name=f"ur-emulator {client.peer}", daemon=True
            ).start()

    def _client_loop(self, client: _Client) -> None:
        buffer = b""
        try:
            while not self._stop.is_set():
                readable, _, _ = select.select([client.sock], [], [], 0.1)
                if not readable:
                    continue
                chunk = client.sock.recv(65536)
                if not chunk:
                    break
                buffer += chunk
                while len(buffer) >= HEADER.size:
                    size, kind = HEADER.unpack_from(buffer)
                    if size < HEADER.size:  # not RTDE: drop the connection
                        return
                    if len(buffer) < size:
                        break
                    payload, buffer = buffer[HEADER.size : size], buffer[size:]
                    self._handle(client, kind, payload)
        except (OSError, ValueError):
            pass
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
                for name in [n for n, owner in self._input_owner.items() if owner is client]:
                    del self._input_owner[name]
            _close(client.sock)

    def _handle(self, client: _Client, kind: int, payload: bytes) -> None:
        if kind == REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            accepted = version == PROTOCOL_VERSION
            if accepted:
                client.protocol = version
            client.send(_package(kind, bytes([accepted])))
        elif kind == GET_URCONTROL_VERSION:
            client.send(_package(kind, struct.pack(">IIII", *self.controller_version)))
        elif kind == TEXT_MESSAGE:
            self.messages.append(_unpack_text_message(payload))
        elif kind == SETUP_OUTPUTS:
            client.send(_package(kind, self._setup_outputs(client, payload)))
        elif kind == SETUP_INPUTS:
            client.send(_package(kind, self._setup_inputs(client, payload)))
        elif kind == START:
            with self._lock:
                cycle = self._cycle
                for recipe in client.outputs.values():
                    recipe.next_cycle = float(cycle)
                client.streaming = True
            client.send(_package(kind, b"\x01"))
        elif kind == PAUSE:
            client.streaming = False
            client.send(_package(kind, b"\x01"))
        elif kind == DATA_PACKAGE:
            recipe = client.inputs.get(payload[0]) if payload else None
            if recipe is None:
                client.send(
                    pack_text_message(f"data package for unknown input recipe {payload[:1].hex()}", level=ERROR)
                )
                return
            names, packer = recipe
            flat = list(packer.unpack(payload[1 : 1 + packer.size]))
            with self._lock:
                for name in names:
                    width = _width(INPUT_TYPES[name])
                    value, flat = (tuple(flat[:width]) if width > 1 else flat[0]), flat[width:]
                    self._inputs[name] = value
        else:
            client.send(pack_text_message(f"unknown package type {kind}", level=ERROR))

    def _setup_outputs(self, client: _Client, payload: bytes) -> bytes:
        (frequency,) = struct.unpack(">d", payload[:8])
        names = _names(payload[8:])
        types = [OUTPUT_TYPES.get(name, "NOT_FOUND") for name in names]
        ok = bool(names) and "NOT_FOUND" not in types
        if not 0 < frequency <= self.cycle_hz:
            ok = False
            client.send(
                pack_text_message(
                    f"output frequency {frequency:g} Hz: must be within (0, {self.cycle_hz:g}] on this controller",
                    level=ERROR,
                )
            )
        recipe_id = 0
        if ok:
            with self._lock:
                recipe_id = len(client.outputs) + 1
                packer = struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types))
                client.outputs[recipe_id] = _OutputRecipe(recipe_id, names, packer, self.cycle_hz / frequency)
        return bytes([recipe_id]) + ",".join(types).encode()

    def _setup_inputs(self, client: _Client, payload: bytes) -> bytes:
        names = _names(payload)
        with self._lock:
            types = [INPUT_TYPES.get(name, "NOT_FOUND") for name in names]
            types = [
                "IN_USE" if t != "NOT_FOUND" and self._input_owner.get(n, client) is not client else t
                for n, t in zip(names, types)
            ]
            recipe_id = 0
            if names and not {"NOT_FOUND", "IN_USE"} & set(types):
                recipe_id = len(client.inputs) + 1
                client.inputs[recipe_id] = (names, struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types)))
                for name in names:
                    self._input_owner[name] = client
        return bytes([recipe_id]) + ",".join(types).encode()


def _names(raw: bytes) -> list[str]:
    """Comma-separated variable names; an empty last name (a trailing comma) is ignored."""
    names = raw.decode(errors="replace").split(",")
    if names and names[-1] == "":
        names.pop()
    return names


def _width(rtde_type: str) -> int:
    fmt = TYPE_FORMATS[rtde_type]
    return int(fmt[0]) if fmt[0].isdigit() else 1


def _unpack_text_message(payload: bytes) -> str:
    n = payload[0] if payload else 0
    return payload[1 : 1 + n].decode(errors="replace")


def _close(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    sock.close()


# ---------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate ur`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--address",
        default="127.0.0.1",
        help="IPv4 address to serve RTDE on, port 30004 (default 127.0.0.1); a loopback address 127.0.0.x keeps "
        "the emulator on this machine, any other address of this machine (0.0.0.0: all of them) serves the network",
    )
    parser.add_argument(
        "--model",
        default="ur5e",
        choices=list(UR_DH),
        help="UR model: its DH geometry; ur3/ur5/ur10 are CB3 (3.x controller, 125 Hz), "
        "the others e-Series (5.x, 500 Hz) (default ur5e)",
    )
    parser.add_argument(
        "--encoder-noise",
        type=float,
        default=1e-7,
        help="std of each joint reading around the true angle, rad (0: the world's exact pose; default 1e-7)",
    )
    parser.add_argument(
        "--tcp-offset",
        default="0,0,0,0,0,0",
        metavar="X,Y,Z,RX,RY,RZ",
        help="the installation's TCP in the flange (m, rotation vector in rad): actual_TCP_pose "
        "is then that point's pose (default: none, the flange)",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve RTDE, the arm moved by ``world``, until Ctrl-C, SIGTERM or ``--duration``; the first line printed
    names the address. Exit status 0."""
    try:
        tcp_offset = tuple(float(x) for x in args.tcp_offset.split(","))
        emulator = UREmulator(
            world, address=args.address, model=args.model, encoder_noise=args.encoder_noise, tcp_offset=tcp_offset
        )
        emulator.start()
    except ValueError as exc:
        raise ConfigError(f"emulate ur: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"emulate ur: cannot serve on {args.address}:{RTDE_PORT}: {exc.strerror or exc}") from None
    with emulator:
        serve_until_stopped(
            args.duration,
            ready=lambda: print(
                f"UR {args.model} RTDE emulator on {emulator.address}:{emulator.port} "
                f"(controller {'.'.join(map(str, emulator.controller_version))}, {emulator.cycle_hz:g} Hz)",
                flush=True,
            ),
        )
    inputs = emulator.inputs()
    print(
        f"sent {emulator.packages_sent} data packages; {len(inputs)} input field(s) written"
        + (f": {', '.join(sorted(inputs))}" if inputs else ""),
        flush=True,
    )
    return 0


@hookimpl
def register_emulators(register):
    register(
        "ur",
        EmulatorCommand(
            help="Universal Robots controller: RTDE v2 on port 30004 (e-Series 500 Hz, CB3 125 Hz)",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
        ),
    )
