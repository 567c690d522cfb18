"""The ``ur_rtde`` kinematics and the RTDE emulator: ur-rtde's own client against the emulated controller.

ur-rtde's constructors hold the GIL while they wait for the controller, so a
ur-rtde client and the emulator cannot share a process: the emulator runs as
``hapticlab emulate ur`` in a child process where this process uses ur-rtde (the
receive interface, our plugin), and ur-rtde runs in a child process where the
test reads the emulator's Python API (the input registers). ur-rtde always
uses port 30004, so each test has its own 127.0.0.x.
"""

from __future__ import annotations

import math
import signal
import socket
import struct
import sys
import time
from contextlib import contextmanager

import numpy as np
import pytest

from hapticlab.core.aligner import Aligner
from hapticlab.core.frames import matrix_from_quat_wxyz, quat_from_rotvec, quat_wxyz_from_matrix
from hapticlab.core.host.interfaces import EmitsEvents, KinematicsSource, MeasuresWrench
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.types import WrenchSample
from hapticlab.plugins.kinematics.ur_arm import URArm
from hapticlab.plugins.kinematics.ur_emulator import UREmulator
from hapticlab.plugins.kinematics.ur_rtde import URRTDEKinematics
from hapticlab.plugins.simworld import SimWorld
from hapticlab.plugins.simworld.robot_wrench import RobotWrench
from hapticlab.sessions.config import load_config

SEED = 7


def demo_world() -> SimWorld:
    """The world ``hapticlab emulate ur --seed 7`` moves the arm with: the demo preset's, seed 7."""
    return SimWorld.from_config({**load_config("demo")[0]["world"], "seed": SEED})


EMULATOR = "import sys\nfrom hapticlab.sessions.cli import main\nsys.exit(main(['emulate', 'ur', *sys.argv[1:]]))\n"
"""``hapticlab emulate ur`` with the arguments given after ``-c EMULATOR``."""


@contextmanager
def emulator_process(spawn_process, address: str, *args: str):
    """``hapticlab emulate ur`` in a child process: yields it once it has printed its address; ends it after."""
    process = spawn_process(
        [sys.executable, "-c", EMULATOR, "--address", address, "--seed", str(SEED), *args], f"emulate ur on {address}"
    )
    try:
        first = process.first_line()
        assert f"on {address}:30004" in first, first
        yield process
    finally:
        process.finish()


def wait_for(condition, timeout: float = 10.0, interval: float = 0.01):
    """Poll until ``condition()`` is truthy (a deadline against hanging, not a timing assertion)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"condition not met within {timeout} s")


def same_rotation(quat_a: np.ndarray, quat_b: np.ndarray) -> float:
    """Largest element difference of the two rotation matrices."""
    return float(
        np.abs(matrix_from_quat_wxyz(np.atleast_2d(quat_a)) - matrix_from_quat_wxyz(np.atleast_2d(quat_b))).max()
    )


def world_quat(world: SimWorld, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R_BE, p_BoEo_B = world.pose(np.asarray(t, dtype=float))
    return quat_wxyz_from_matrix(R_BE), p_BoEo_B


def match_cycles(world: SimWorld, quat_BE: np.ndarray, cycle_s: float) -> np.ndarray:
    """The controller cycle of each pose: the one where the world has exactly that orientation.

    The first pose is searched over the first 20 s; each next one at the next
    cycles (missed packages leave gaps).
    """
    grid = np.arange(int(20.0 / cycle_s))
    R_BE, _ = world.pose(grid * cycle_s)
    first = int(np.argmin(np.abs(R_BE - matrix_from_quat_wxyz(quat_BE[:1])).max(axis=(1, 2))))
    cycles = [first]
    for q in quat_BE[1:]:
        ahead = cycles[-1] + np.arange(1, 50)
        candidates, _ = world.pose(ahead * cycle_s)
        errors = np.abs(candidates - matrix_from_quat_wxyz(q[None])).max(axis=(1, 2))
        cycles.append(int(ahead[int(np.argmin(errors))]))
    return np.array(cycles)


# ---------------------------------------------------------------------- ur-rtde's own client


def test_ur_rtde_receive_interface_reads_the_simulated_arm(spawn_process):
    """ur-rtde's unmodified RTDEReceiveInterface (default recipe and a chosen one) reads the world's pose.

    The emulator's encoders jitter (1e-7 rad per joint): the pose is the forward
    kinematics of the reported joints, within ~1e-6 of the world's, never equal.
    """
    import rtde_receive

    world, arm = demo_world(), URArm("ur5e")
    with emulator_process(spawn_process, "127.0.0.71"):
        chosen = rtde_receive.RTDEReceiveInterface("127.0.0.71", 500.0, ["timestamp", "actual_TCP_pose", "actual_q"])
        every = rtde_receive.RTDEReceiveInterface("127.0.0.71")  # the default recipe: every output ur-rtde knows
        try:
            wait_for(lambda: chosen.getTimestamp() > 0.1 and every.getTimestamp() > 0.1)
            assert every.getRobotMode() == 7 and every.getSafetyMode() == 1  # running, normal
            for _ in range(5):
                while True:  # one package's fields: the timestamp the same before and after
                    t = chosen.getTimestamp()
                    pose, q = chosen.getActualTCPPose(), chosen.getActualQ()
                    if chosen.getTimestamp() == t:
                        break
                assert round(t * 500) == pytest.approx(t * 500, abs=1e-6)  # whole 2 ms cycles
                quat, p_BoEo_B = world_quat(world, [t])
                rotation_error = same_rotation(quat_from_rotvec(np.array(pose[3:])), quat)
                assert 0 < rotation_error < 2e-6
                np.testing.assert_allclose(pose[:3], p_BoEo_B[0], atol=2e-6)
                R_BE, p = arm.forward(np.array(q))
                assert np.abs(R_BE - matrix_from_quat_wxyz(quat_from_rotvec(np.array(pose[3:]))[None])[0]).max() < 1e-9
                np.testing.assert_allclose(p, pose[:3], atol=1e-9)
                time.sleep(0.05)
        finally:
            chosen.disconnect()
            every.disconnect()


# ---------------------------------------------------------------------- the plugin


def collect(kinematics: URRTDEKinematics, count: int) -> list:
    samples = []
    wait_for(lambda: samples.extend(kinematics.read(time.monotonic_ns())) or len(samples) >= count)
    return samples


@pytest.mark.parametrize(
    ("address", "model", "rate_hz", "cycle_s"),
    [("127.0.0.72", "ur5e", 500.0, 0.002), ("127.0.0.73", "ur5", 125.0, 0.008)],
)
def test_plugin_reads_the_simulated_poses_every_cycle_or_counts_the_missed(
    address, model, rate_hz, cycle_s, spawn_process
):
    """Poses equal the world's at consecutive controller cycles (gaps = packages_missed), joints FK to the pose."""
    world, arm = demo_world(), URArm(model)
    with emulator_process(spawn_process, address, "--model", model, "--encoder-noise", "0"):
        kinematics = URRTDEKinematics(address=address, rate_hz=rate_hz, model=model)
        assert isinstance(kinematics, KinematicsSource) and isinstance(kinematics, EmitsEvents)
        kinematics.open(time.monotonic_ns())
        try:
            samples = collect(kinematics, 150)
        finally:
            kinematics.close()
    assert not [e for e in kinematics.drain_events() if e.kind == "kinematics_tcp_offset"]  # the flange
    quat_BE = np.array([s.quat_BE for s in samples])
    cycles = match_cycles(world, quat_BE, cycle_s)
    quats, p_BoEo_B = world_quat(world, cycles * cycle_s)
    assert max(same_rotation(a, b) for a, b in zip(quat_BE, quats)) < 1e-9
    np.testing.assert_allclose([s.p_BoEo_B for s in samples], p_BoEo_B, atol=1e-12)
    gaps = np.diff(cycles) - 1
    assert gaps.min() >= 0
    assert gaps.sum() == kinematics.packages_missed  # every missed package counted, none invented
    assert kinematics.packages_missed < len(samples) // 2
    t_ns = np.array([s.t_ns for s in samples])
    assert np.all(np.diff(t_ns) > 0)
    steps = np.diff(t_ns)[gaps == 0]
    assert np.median(steps) == pytest.approx(cycle_s * 1e9, rel=1e-3)  # the controller's clock, not arrival jitter
    for s in samples[::10]:
        R_BE, p = arm.forward(s.joints)
        assert np.abs(R_BE - matrix_from_quat_wxyz(s.quat_BE[None])[0]).max() < 1e-9
        np.testing.assert_allclose(p, s.p_BoEo_B, atol=1e-9)
    # the arm's own wrench (actual_TCP_force, a fifth output): the world's contact with the UR5e's error model
    assert isinstance(kinematics, MeasuresWrench) and kinematics.wrench_accuracy_N == 4.0
    t = cycles * cycle_s
    expected = RobotWrench(world).measured(t, np.round(t * 1e9).astype(np.int64))
    np.testing.assert_allclose([s.wrench_B for s in samples], expected, atol=1e-9)
    # joint velocities: the emulator's difference of consecutive q over their time
    a, b = samples[-2], samples[-1]
    if cycles[-1] - cycles[-2] == 1:
        np.testing.assert_allclose(b.joint_velocities, (b.joints - a.joints) / cycle_s, rtol=1e-6, atol=1e-9)


def test_a_cb3_refuses_500_hz_and_the_plugin_says_so(spawn_process):
    with emulator_process(spawn_process, "127.0.0.74", "--model", "ur5"):
        kinematics = URRTDEKinematics(address="127.0.0.74", rate_hz=500.0)
        with pytest.raises(ConnectionError, match=r"UR controller 127\.0\.0\.74:30004 \(RTDE at 500 Hz\)"):
            kinematics.open(time.monotonic_ns())


def test_emulator_stopped_no_fresh_poses_the_orientation_goes_stale_and_an_event_says_so(spawn_process):
    """The fail-safe: no pose after the controller is gone, so the aligner marks newer wrenches stale."""
    with emulator_process(spawn_process, "127.0.0.75") as emulator:
        kinematics = URRTDEKinematics(address="127.0.0.75", rate_hz=500.0, receive_timeout=0.05)
        kinematics.open(time.monotonic_ns())
        samples = collect(kinematics, 20)
        emulator.finish()
    try:
        events = []
        wait_for(
            lambda: events.extend(kinematics.drain_events()) or any(e.kind == "kinematics_timeout" for e in events)
        )
        samples += kinematics.read(time.monotonic_ns())
        after_ns = time.monotonic_ns()
        assert kinematics.read(after_ns + 10**9) == []  # nothing new, whatever the time
    finally:
        kinematics.close()
    timeout = next(e for e in events if e.kind == "kinematics_timeout")
    assert "no RTDE package from UR controller 127.0.0.75" in timeout.message
    assert "haptic force held at zero" in timeout.message
    aligner = Aligner(kinematics.rate_hz)
    aligner.add_poses(samples)
    last_ns = samples[-1].t_ns
    wrenches = [WrenchSample(t, np.zeros(3), np.zeros(3)) for t in (last_ns, last_ns + 5_000_000, after_ns)]
    block = aligner.align(wrenches)
    assert block.stale.tolist() == [False, True, True]


def _events_when_open_returns(spawn_process, address: str) -> list:
    """The events drained right after ``open`` returns, against an emulated ur5e whose installation sets a TCP
    100 mm out along z, turned 0.5 rad about it."""
    with emulator_process(spawn_process, address, "--tcp-offset", "0,0,0.1,0,0,0.5"):
        kinematics = URRTDEKinematics(address=address, model="ur5e")
        kinematics.open(time.monotonic_ns())
        try:
            return kinematics.drain_events()
        finally:
            kinematics.close()


def test_a_tcp_offset_in_the_installation_is_an_event(spawn_process):
    """With ``model`` set, a reported pose that is not the flange's FK (a TCP 100 mm out, turned 0.5 rad) is named."""
    (event,) = [e for e in _events_when_open_returns(spawn_process, "127.0.0.85") if e.kind == "kinematics_tcp_offset"]
    assert "actual_TCP_pose is 100.0 mm and 0.500 rad from the ur5e flange" in event.message
    assert event.data["distance_m"] == pytest.approx(0.1, abs=1e-5)


def test_the_first_package_s_events_are_there_when_open_returns(monkeypatch, spawn_process):
    """``open`` returns once the first package is kept; its TCP check's event is published with it, not after:
    with the check made slow (0.2 s, as a loaded machine can make it), the event is there when ``open``
    returns (a package counted before its events were published lost this race under CI load)."""
    check = URRTDEKinematics._check_tcp

    def slow_check(self, received_ns, sample):
        time.sleep(0.2)
        return check(self, received_ns, sample)

    monkeypatch.setattr(URRTDEKinematics, "_check_tcp", slow_check)
    events = _events_when_open_returns(spawn_process, "127.0.0.88")
    assert [e.kind for e in events].count("kinematics_tcp_offset") == 1


def test_connection_refused_names_the_controller():
    kinematics = URRTDEKinematics(address="127.0.0.76")  # nothing listens there
    with pytest.raises(ConnectionError, match=r"127\.0\.0\.76:30004"):
        kinematics.open(time.monotonic_ns())


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({}, "kinematics.address: must be the UR controller's IP address or host name"),
        ({"address": "robot..lab"}, "kinematics.address: must be an IP address or a host name, got 'robot..lab'"),
        ({"address": "10.0.0.2", "rate_hz": 1000}, "kinematics.rate_hz: must be a finite number > 0 and <= 500 Hz"),
        (
            {"address": "10.0.0.2", "receive_timeout": 0},
            "kinematics.receive_timeout: must be a finite number > 0 and <= 1 s",
        ),
        (
            {"address": "10.0.0.2", "frequency": 500},
            "kinematics.frequency: unknown option; known options: address, follow, follow_rate_hz, model, rate_hz, "
            "receive_timeout",
        ),
        ({"address": 10}, "kinematics.address: must be a string, got 10"),
        ({"address": "10.0.0.2", "model": "ur7e"}, "kinematics.model: must be 'ur3e', 'ur5e', "),
        ({"address": "10.0.0.2", "follow_rate_hz": 100}, "kinematics.follow_rate_hz: must be left out unless follow"),
    ],
)
def test_bad_config_is_one_line_naming_the_key(options, message):
    with pytest.raises(ConfigError) as info:
        Registry().create("kinematics", "ur_rtde", options, where="kinematics")
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


# ---------------------------------------------------------------------- the emulator's protocol


class RawClient:
    """A bare RTDE protocol-2 client (to see what ur-rtde hides: recipe ids, types, NOT_FOUND)."""

    def __init__(self, address: str, port: int):
        self.sock = socket.create_connection((address, port), timeout=5.0)
        self.buffer = b""

    def send(self, kind: str, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)

    def receive(self, kind: str) -> bytes:
        """The payload of the next package of ``kind`` (skipping others, e.g. data and text messages)."""
        while True:
            while len(self.buffer) < 3 or len(self.buffer) < struct.unpack_from(">H", self.buffer)[0]:
                chunk = self.sock.recv(65536)
                assert chunk, "the emulator closed the connection"
                self.buffer += chunk
            size, got = struct.unpack_from(">HB", self.buffer)
            payload, self.buffer = self.buffer[3:size], self.buffer[size:]
            if got == ord(kind):
                return payload

    def request(self, kind: str, payload: bytes = b"") -> bytes:
        self.send(kind, payload)
        return self.receive(kind)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def emulator():
    with UREmulator(SimWorld.from_config({"seed": SEED}), address="127.0.0.1", port=0) as emu:
        yield emu


def test_output_setup_types_not_found_and_trailing_comma(emulator):
    client = RawClient(emulator.address, emulator.port)
    try:
        assert client.request("V", struct.pack(">H", 2)) == b"\x01"
        assert struct.unpack(">IIII", client.request("v"))[0] == 5  # e-Series
        reply = client.request("O", struct.pack(">d", 250.0) + b"timestamp,no_such_output,actual_q")
        assert reply[0] == 0 and reply[1:] == b"DOUBLE,NOT_FOUND,VECTOR6D"  # setup failed, the culprit named
        reply = client.request(
            "O", struct.pack(">d", 250.0) + b"timestamp,actual_TCP_pose,"
        )  # ur-rtde's trailing comma
        assert reply[0] == 1 and reply[1:] == b"DOUBLE,VECTOR6D"
        assert client.request("O", struct.pack(">d", 501.0) + b"timestamp")[0] == 0  # faster than the controller
        assert client.request("S") == b"\x01"
        stamps = []
        for _ in range(3):
            payload = client.receive("U")
            assert payload[0] == 1
            stamps.append(struct.unpack(">d6d", payload[1:])[0])
        assert np.allclose(np.diff(stamps), 0.004)  # 250 Hz: every second 2 ms cycle
        assert stamps[0] * 1e9 <= time.monotonic_ns() - emulator.t0_ns  # timestamp 0 is t0_ns
        assert client.request("P") == b"\x01"
    finally:
        client.close()


def test_input_registers_from_a_raw_client_are_kept_and_read_back(emulator):
    client, other = RawClient(emulator.address, emulator.port), RawClient(emulator.address, emulator.port)
    try:
        client.request("V", struct.pack(">H", 2))
        reply = client.request("I", b"input_double_register_5,input_int_register_30,input_bit_registers0_to_31")
        assert reply == b"\x01DOUBLE,INT32,UINT32"
        assert client.request("I", b"input_double_register_5,no_such_input")[1:] == b"DOUBLE,NOT_FOUND"
        other.request("V", struct.pack(">H", 2))
        assert other.request("I", b"input_double_register_5") == b"\x00IN_USE"  # another client writes it
        client.send("U", bytes([1]) + struct.pack(">diI", -2.5, 42, 0b1011))
        inputs = wait_for(lambda: emulator.inputs() or None)
        assert inputs == {
            "input_double_register_5": -2.5,
            "input_int_register_30": 42,
            "input_bit_registers0_to_31": 0b1011,
        }
        reply = client.request("O", struct.pack(">d", 125.0) + b"input_double_register_5,input_int_register_30")
        assert reply == b"\x01DOUBLE,INT32"
        client.request("S")
        payload = client.receive("U")
        assert struct.unpack(">di", payload[1:]) == (-2.5, 42)
    finally:
        client.close()
        other.close()


IO_CLIENT = (
    "import sys, rtde_io\n"
    "io = rtde_io.RTDEIOInterface(sys.argv[1])\n"
    "ok = io.setInputDoubleRegister(18, 1.25) and io.setInputIntRegister(20, -7)\n"
    "io.disconnect()\n"
    "sys.exit(0 if ok else 1)\n"
)


def test_input_registers_written_by_ur_rtde_io_interface_reach_the_emulator(spawn_process):
    """ur-rtde's RTDEIOInterface needs only RTDE (no URScript port): its register setters land in the emulator."""
    with UREmulator(SimWorld.from_config({"seed": SEED}), address="127.0.0.77") as emu:
        client = spawn_process([sys.executable, "-c", IO_CLIENT, "127.0.0.77"], "ur-rtde's RTDEIOInterface")
        assert client.wait_for_exit() == 0, client.stderr.read()
        inputs = wait_for(lambda: (lambda i: i if "input_int_register_20" in i else None)(emu.inputs()))
    assert inputs["input_double_register_18"] == 1.25
    assert inputs["input_int_register_20"] == -7


def test_emulator_refuses_a_model_that_cannot_reach_the_world():
    world = SimWorld.from_config({"seed": SEED, "robot": {"position": [0.7, 0.0, 0.35]}})
    UREmulator(world, model="ur5e")  # 0.85 m of reach
    with pytest.raises(
        ValueError, match=r"model: must reach the world's flange position \[0\.7, 0\.0, 0\.35\] m at t = 0, got 'ur3e'"
    ):
        UREmulator(world, model="ur3e")  # 0.5 m


def test_a_given_start_time_is_the_controllers_timestamp_zero():
    """start(t0_ns) puts timestamp 0 where another emulator's world time 0 is (one world for a rig)."""
    t0_ns = time.monotonic_ns() - 3 * 10**9  # a world that started 3 s ago
    with UREmulator(SimWorld.from_config({"seed": SEED}), address="127.0.0.1", port=0).start(t0_ns) as emu:
        assert emu.t0_ns == t0_ns
        client = RawClient(emu.address, emu.port)
        try:
            client.request("V", struct.pack(">H", 2))
            client.request("O", struct.pack(">d", 500.0) + b"timestamp")
            client.request("S")
            (stamp,) = struct.unpack(">d", client.receive("U")[1:])
            received_ns = time.monotonic_ns()
        finally:
            client.close()
    assert 3.0 <= stamp <= (received_ns - t0_ns) * 1e-9  # the controller's clock counts from t0_ns: by now, no more


def test_emulate_ur_runs_for_its_duration_and_exits_cleanly(spawn_process):
    emulator = spawn_process(
        [sys.executable, "-c", EMULATOR, "--address", "127.0.0.78", "--model", "ur10e", "--duration", "0.2"],
        "emulate ur for 0.2 s",
    )
    assert emulator.wait_for_exit() == 0, emulator.stderr.read()
    lines = emulator.stdout.read().splitlines()
    assert lines[0] == "UR ur10e RTDE emulator on 127.0.0.78:30004 (controller 5.15.0.0, 500 Hz)"
    assert lines[-1] == "sent 0 data packages; 0 input field(s) written"


def test_emulate_ur_bad_input_is_one_line_naming_it(capsys):
    from hapticlab.sessions.cli import main

    assert main(["emulate", "ur", "--session", "no_such.toml"]) == 2
    assert "no_such.toml: no such session file" in capsys.readouterr().err
    assert main(["emulate", "ur", "--address", "192.0.2.1", "--allow-network"]) == 2  # not an address of this machine
    assert "emulate ur: cannot serve on 192.0.2.1:30004" in capsys.readouterr().err


def test_encoders_jitter_so_a_still_arm_never_reports_a_frozen_pose():
    """On a held pose the reported pose still changes every cycle (the frozen-pose watch needs it), and it is
    always the forward kinematics of the reported joints; without jitter it is bit-identical."""
    world = SimWorld.from_config({"seed": SEED, "motion": {"script": "hold"}})
    arm = URArm("ur5e")
    jitter, exact = UREmulator(world), UREmulator(world, encoder_noise=0.0)
    a, b = jitter.state(100), jitter.state(101)
    assert a["actual_TCP_pose"] != b["actual_TCP_pose"] and a["actual_q"] != b["actual_q"]
    for state in (a, b):
        R_BE, p = arm.forward(np.array(state["actual_q"]))
        np.testing.assert_allclose(p, state["actual_TCP_pose"][:3], atol=1e-12)
        assert (
            np.abs(
                R_BE - matrix_from_quat_wxyz(quat_from_rotvec(np.array(state["actual_TCP_pose"][3:]))[None])[0]
            ).max()
            < 1e-12
        )
    np.testing.assert_allclose(a["actual_TCP_pose"][:3], world.pose(0.2)[1][0], atol=1e-6)
    assert exact.state(100)["actual_TCP_pose"] == exact.state(101)["actual_TCP_pose"]
    with pytest.raises(ValueError, match=r"encoder_noise: must be a finite number >= 0 and <= 0.001 rad, got 0.1"):
        UREmulator(world, encoder_noise=0.1)


STALLING_EMULATOR = (
    "import sys, time\n"
    "from hapticlab.plugins.kinematics.ur_emulator import UREmulator\n"
    "from hapticlab.plugins.simworld import SimWorld\n"
    "t0 = time.monotonic_ns()\n"
    "emu = UREmulator(SimWorld.from_config({'seed': int(sys.argv[2])}), address=sys.argv[1],\n"
    "                 stalls=[(0.5, 0.2), (0.9, 0.2)]).start(t0_ns=t0)\n"
    "print(t0, flush=True)\n"
    "time.sleep(20)\n"
)


def test_every_missed_package_is_reported_by_the_time_the_plugin_closes(monkeypatch, spawn_process):
    """Missed-package events are rate limited (one a second; here one a minute, so that whatever the machine's
    load makes of the first event's time, everything after it is held): two stalls 0.4 s apart (the emulator
    sends nothing for 0.2 s each, connection open) and a close 0.3 s after the second: the packages held back
    are reported when the plugin closes, so the events add up to every package missed.
    (The emulator in its own process: ur-rtde's client holds the GIL while it connects.)"""
    monkeypatch.setattr("hapticlab.plugins.kinematics.ur_rtde.MISSED_EVENT_INTERVAL_NS", 60_000_000_000)
    process = spawn_process([sys.executable, "-c", STALLING_EMULATOR, "127.0.0.78", str(SEED)], "the stalling emulator")
    try:
        t0 = int(process.first_line())
        kinematics = URRTDEKinematics(address="127.0.0.78", rate_hz=500.0, receive_timeout=1.0)
        kinematics.open(time.monotonic_ns())
        wait_for(lambda: time.monotonic_ns() - t0 > 1.4e9, timeout=20)
        before_close = [e for e in kinematics.drain_events() if e.kind == "kinematics_missed"]
        kinematics.close()
    finally:
        process.finish(signal.SIGKILL)
    at_close = [e for e in kinematics.drain_events() if e.kind == "kinematics_missed"]
    assert kinematics.packages_missed >= 2 * 0.9 * 0.2 * 500  # both stalls
    assert sum(e.data["missed"] for e in before_close) < kinematics.packages_missed  # the second one held back
    assert sum(e.data["missed"] for e in before_close + at_close) == kinematics.packages_missed
    assert at_close[-1].data["missed_total"] == kinematics.packages_missed


class ScriptedRTDE:
    """ur-rtde's RTDEReceiveInterface as the plugin's thread reads it, replaying one package per full read (or
    per skipped one) from a list of controller timestamps, s."""

    def __init__(self, stamps: list[float]):
        self.stamps, self.k, self.confirming, self.advance = stamps, 0, False, False

    def isConnected(self) -> bool:  # noqa: N802 (ur-rtde's name)
        return self.k < len(self.stamps)

    def getTimestamp(self) -> float:  # noqa: N802 (ur-rtde's name)
        if self.advance:
            self.k, self.advance = self.k + 1, False
        t = self.stamps[min(self.k, len(self.stamps) - 1)]
        if self.confirming:  # the read's second look at the timestamp: this package is done
            self.confirming, self.advance = False, True
        elif not 0.0 <= t <= 1e9:  # a package the plugin skips
            self.advance = True
        return t

    def getActualTCPPose(self) -> list[float]:  # noqa: N802 (ur-rtde's name)
        return [0.4, 0.0, 0.3, math.pi, 0.0, 0.0]

    def getActualQ(self) -> list[float]:  # noqa: N802 (ur-rtde's name)
        return [0.0] * 6

    def getActualQd(self) -> list[float]:  # noqa: N802 (ur-rtde's name)
        self.confirming = True
        return [0.0] * 6

    def getActualTCPForce(self) -> list[float]:  # noqa: N802 (ur-rtde's name)
        return [0.0] * 6

    def disconnect(self) -> None:
        pass


def test_a_package_with_an_impossible_timestamp_is_skipped_and_the_stream_goes_on(monkeypatch):
    """NaN, inf, 1e300 s (what a truncated package parses to) or a negative time: counted, one event, and the
    next packages are read (the thread used to die on round(nan) or overflow the clock's int64)."""
    stamps = [0.002 * k for k in range(1, 9)] + [math.nan, math.inf, 1e300, -5.0] + [0.002 * k for k in range(9, 17)]
    fake = ScriptedRTDE(stamps)
    monkeypatch.setattr(URRTDEKinematics, "_connect", lambda self: fake)
    plugin = URRTDEKinematics("127.0.0.1", 500.0)
    plugin.open(0)
    deadline = time.monotonic() + 10.0
    while fake.isConnected() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not fake.isConnected(), f"the thread stopped reading at package {fake.k} of {len(stamps)}"
    alive = plugin._thread is not None and plugin._thread.is_alive()
    poses, events = plugin.read(2**62), plugin.drain_events()
    plugin.close()
    assert alive and len(poses) == 16 and plugin.packages_bad == 4
    assert np.all(np.diff([p.t_ns for p in poses]) > 0)
    bad = [e for e in events if e.kind == "kinematics_bad_package"]
    assert len(bad) == 1 and "timestamp nan s is no controller's clock" in bad[0].message, bad
