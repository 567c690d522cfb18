"""Teleoperation end to end: the master's handle moves the simulated robot, the tissue it presses comes back as force.

The first tests use a scripted hand (a haptic output whose handle follows a
function of the session's clock), so a non-realtime session is deterministic;
the last one goes over a real pseudo-terminal to the master emulator in
real time.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from processes import hapticlab_command
from scipy.spatial.transform import Rotation

from hapticlab.core import hookimpl
from hapticlab.core.frames import matrix_from_quat_wxyz
from hapticlab.core.host.registry import ConfigError, Registry, make_plugin_manager
from hapticlab.core.types import DeviceState
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import read_recording

DWELL_S = 0.3
TURN_RAD_S = 3.0  # the target's turn rate in these tests (the tour is over in ~4 s)
PRESS_AT = 5.0  # s: when the scripted hand starts pressing (the tour is over by then)
HAND_PRESS_AT = 7.0  # s from the master emulator's first handshake: the lab's tour waits for the arm, so later
FELT_TOLERANCE_N = 0.35  # N: the estimator's error in contact and one reading's noise (95th percentile)
SCALE = 0.5
TIP_ABOVE_TISSUE = 0.005  # m: the preset's tissue surface is 5 mm under the tool tip
STIFFNESS = 300.0  # N/m, the tissue's


def hand_z(t: float) -> float:
    """The scripted hand in D (m): still during the tour, then presses 5 cm down and back up over 2 s,
    clutched from 7.5 to 8.0 s while it moves 2 cm sideways (along D's x), lost from 8.5 to 8.7 s, silent from 9.0
    to 9.1 s (the device repeats its state of 9.0 s, stamp and all)."""
    s = t - PRESS_AT
    return -0.025 * (1 - math.cos(2 * math.pi * s / 2.0)) if 0 <= s <= 2.0 else 0.0


def hand_x(t: float) -> float:
    return 0.02 * min(max((t - 7.5) / 0.5, 0.0), 1.0)


class ScriptedHand:
    """A haptic output whose handle follows ``hand_x``/``hand_z`` on the session clock (HapticOutput)."""

    def __init__(self, rate_hz: float = 1000.0):
        self.rate_hz = rate_hz
        self.t0_ns = None
        self.t_ns = 0
        self.sent = []

    def open(self):
        pass

    def close(self):
        pass

    def send(self, command):
        if self.t0_ns is None:
            self.t0_ns = command.t_ns
        self.t_ns = command.t_ns
        self.sent.append(command)

    def state(self):
        t = (self.t_ns - self.t0_ns) * 1e-9
        if 8.5 <= t < 8.7:
            return None  # lost
        t_ns = self.t_ns
        if 9.0 <= t < 9.1:  # silent: the state of 9.0 s again
            t, t_ns = 9.0, self.t0_ns + 9_000_000_000
        clutch = 7.5 <= t < 8.0
        return DeviceState(
            t_ns, np.array([1.0, 0.0, 0.0, 0.0]), np.array([hand_x(t), 0.0, hand_z(t)]), buttons=0b10 if clutch else 0
        )


class HandPlugin:
    @hookimpl
    def register_haptic_outputs(self, register):
        register("scripted_hand", ScriptedHand)


@pytest.fixture(scope="module")
def registry():
    pm = make_plugin_manager(load_entry_points=False)
    pm.register(HandPlugin(), name="tests")
    return Registry(pm)


def teleop_config(*overrides: str, duration: float = 9.5, preset: str = "teleop-emulated"):
    config, _ = load_config(preset)
    return apply_overrides(
        config,
        [
            "session.realtime=false",
            f"session.duration={duration}",
            f"teleop.calibration_dwell_s={DWELL_S}",
            f"teleop.max_angular_speed={TURN_RAD_S}",
            *overrides,
        ],
    )


def tour_end(rec) -> float:
    """When the calibration tour ended, s from the first target."""
    t0 = rec.t_ns("/robot/target")[0]
    calibrated = [t for t, m in rec.topics["/events"] if m["kind"] == "teleop_calibrated"]
    events = [(m["kind"], m["message"]) for _, m in rec.topics["/events"] if m["kind"].startswith("teleop")]
    assert len(calibrated) == 1, f"the calibration tour did not end once: {events[:6]}"
    (t_cal,) = calibrated
    return (t_cal - t0) * 1e-9


@pytest.fixture(scope="module")
def scripted(tmp_path_factory, registry):
    config = teleop_config("haptic.name=scripted_hand")
    session = build_session(config, registry)
    result = run_session(session, out=tmp_path_factory.mktemp("teleop") / "teleop.mcap")
    return result, read_recording(result.path), session


def targets(rec):
    t = rec.t_ns("/robot/target")
    messages = [m for _, m in rec.topics["/robot/target"]]
    p = np.array([m["pose"]["p_BoEo_B"] for m in messages])
    return (t - t[0]) * 1e-9, p, [m["mode"] for m in messages], [m["reason"] for m in messages]


def test_the_robot_tours_then_follows_the_hand_scaled(scripted):
    _result, rec, _ = scripted
    t, p, mode, _ = targets(rec)
    assert len(t) == len(rec.topics["/haptic/command"]) - 1  # one target per tick (the final zero aside)
    t_cal = tour_end(rec)
    assert t_cal < PRESS_AT - 0.3
    touring = t < t_cal - 0.01
    assert set(np.array(mode)[touring]) == {"calibrating"}
    kinds = [m["kind"] for _, m in rec.topics["/events"]]
    assert kinds.index("teleop_calibrated") < kinds.index("teleop_following")
    quat = np.array([m["pose"]["quat_BE"] for _, m in rec.topics["/robot/target"]])
    held = [
        tuple(q) for q, same in zip(quat[touring].round(9), np.all(np.diff(quat[touring], axis=0) == 0, axis=1)) if same
    ]
    assert len(set(held)) == 6  # six orientations held (the start's among them, where the tour ends)
    # the target turned at most TURN_RAD_S: no step a servoing robot could not follow
    turn = 2 * np.arccos(np.minimum(np.abs(np.sum(quat[1:] * quat[:-1], axis=1)), 1.0)) / np.diff(t)
    assert turn.max() <= TURN_RAD_S * (1 + 1e-6)
    # following: the target moves by scale · the hand's move (D = B here), the start captured
    following = (t > t_cal + 0.1) & (t < 7.5)
    assert set(np.array(mode)[following]) == {"following"}
    start = p[np.searchsorted(t, t_cal + 0.1)]
    expected_z = start[2] + SCALE * np.array([hand_z(x) for x in t[following]])
    assert np.abs(p[following, 2] - expected_z).max() < 1e-9
    assert np.ptp(p[following, 0]) < 1e-12 and np.ptp(p[following, 1]) < 1e-12


def test_the_hand_feels_the_tissue_the_tool_presses(scripted):
    _, rec, session = scripted
    world = session.contexts["world"]
    t_cmd = (rec.t_ns("/haptic/command") - rec.t_ns("/robot/target")[0]) * 1e-9
    force_D = rec.field("/haptic/command", "force_D")
    enabled = rec.field("/haptic/command", "enabled").astype(bool)
    assert enabled[(t_cmd > tour_end(rec)) & (t_cmd < 7.5)].all()  # converged during the tour
    # the truth: the tissue's push from the tip's depth (the robot's measured pose)
    t_pose = (rec.t_ns("/kinematics/pose") - rec.t_ns("/robot/target")[0]) * 1e-9
    p_pose = np.array([m["p_BoEo_B"] for _, m in rec.topics["/kinematics/pose"]])
    deepest = (t_pose > PRESS_AT) & (t_pose < PRESS_AT + 2.0)
    tip_z = p_pose[deepest, 2] - world.tool.tip_S[2]  # the tool points straight down again
    depth = (world.contacts[0].surface_B[2] - tip_z).max()
    assert 0.015 < depth < 0.02  # the hand went 5 cm down: 2.5 cm on the robot, 2 cm past the surface
    pressing = (t_cmd > PRESS_AT + 0.6) & (t_cmd < PRESS_AT + 1.4)
    assert (force_D[pressing, 2] > 1.0).all()  # the tissue pushes the hand back up
    limit = session.haptic_settings.max_force
    assert np.linalg.norm(force_D, axis=1).max() <= limit + 1e-9
    assert np.abs(force_D[pressing, 2].max() - min(STIFFNESS * depth, limit)) < 0.3
    free = (t_cmd > tour_end(rec)) & (t_cmd < PRESS_AT)
    assert np.linalg.norm(force_D[free], axis=1).max() < 0.5  # nothing touched: only noise under the deadband


def test_the_clutch_holds_the_robot_and_releasing_it_does_not_jump(scripted):
    _, rec, _ = scripted
    t, p, mode, reason = targets(rec)
    clutched = (t > 7.5 + 0.002) & (t < 8.0)
    assert set(np.array(reason)[clutched]) == {"clutch pressed"}
    assert np.ptp(p[clutched], axis=0).max() < 1e-12  # the hand moved 2 cm: the robot did not
    after = (t > 8.0) & (t < 8.5)
    assert set(np.array(mode)[after]) == {"following"}
    step = np.linalg.norm(np.diff(p[(t > 7.4) & (t < 8.5)], axis=0), axis=1)
    assert step.max() < 1e-6  # re-engaging captured the new offset: no jump


def test_a_master_that_stops_reporting_its_state_holds_the_robot(scripted):
    _, rec, _ = scripted
    t, p, _mode, reason = targets(rec)
    lost = (t > 8.5 + 0.002) & (t < 8.7)
    assert set(np.array(reason)[lost]) == {"no state from the master device"}
    assert np.ptp(p[lost], axis=0).max() < 1e-12
    holding = [m["message"] for _, m in rec.topics["/events"] if m["kind"] == "teleop_holding"]
    assert holding[:2] == ["robot holding: clutch pressed", "robot holding: no state from the master device"]


def test_a_silent_master_gets_zero_force_within_a_tick_of_the_watchdog(scripted):
    """The master repeats its state of 9.0 s until 9.1 s: from the first tick that state is more than 30 ms old
    (the dVRK's watchdog) the force sent to it is zero, saying why, and the robot holds; both come back once it
    speaks again (the robot a tick later), the hand where it left (nothing jumps)."""
    from hapticlab.sessions.live.teleop import WATCHDOG_NS

    _, rec, _ = scripted
    t0 = rec.t_ns("/robot/target")[0]
    commands = rec.topics["/haptic/command"]
    states = rec.t_ns("/haptic/state")
    silent_ticks = []
    for t_ns, m in commands:
        newest = states[states < t_ns]  # the state the tick's command was made with (read after the send)
        if len(newest) and t_ns - newest[-1] > WATCHDOG_NS and 9.0 <= (t_ns - t0) * 1e-9 < 9.2:
            silent_ticks.append(m)
    assert len(silent_ticks) >= 60  # 100 ms silent, less the watchdog's 30 ms, at 1 kHz
    assert all(not m["enabled"] and m["reason"].startswith("the master's state is ") for m in silent_ticks)
    t, p, mode, reason = targets(rec)
    window = (t > 8.95) & (t < 9.3)
    held = window & (np.array(mode) == "holding")
    reasons = [r.split(" is ")[0] for r in np.array(reason)[held]]
    # the tick it speaks again still holds: its command was made (zero) before its state came back
    assert reasons[-1] == "haptic force off" and set(reasons[:-1]) == {"the master's state"}
    assert (np.array(mode)[window & (t > 9.11)] == "following").all()
    assert np.ptp(p[window], axis=0).max() < 1e-12  # the hand is still: the robot never moved


def test_the_target_moves_no_faster_than_its_limit_and_stays_in_its_workspace(registry, tmp_path):
    config = teleop_config(
        "haptic.name=scripted_hand", "teleop.max_speed=0.01", "teleop.workspace_radius=0.008", duration=7.5
    )
    result = run_session(build_session(config, registry), out=tmp_path / "slow.mcap")
    rec = read_recording(result.path)
    t, p, _, _ = targets(rec)
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / np.diff(t)
    assert speed.max() <= 0.01 * (1 + 1e-6)
    distance = np.linalg.norm(p - p[0], axis=1)
    assert distance.max() <= 0.008 + 1e-12
    assert np.isclose(distance.max(), 0.008)  # the hand asked for 2.5 cm: the bound held


def test_teleoperation_needs_a_robot_that_follows_targets():
    config = teleop_config("haptic.name=null")
    config["world"]["motion"] = {"script": "random_tour"}
    with pytest.raises(ConfigError, match=r'teleop.enabled: kinematics .sim. cannot follow a target.*script = "servo"'):
        build_session(config)
    with pytest.raises(ConfigError, match=r"teleop.clutch_button"):
        build_session(teleop_config("haptic.name=null", "teleop.clutch_button=64"))


def holds_explained(rec, after) -> np.ndarray:
    """Check that every target in ``after`` (a mask over /robot/target) follows the hand unless the recording
    shows why not at that very tick; the mask of those held. A paced session meets the master as fast as the
    machine lets the processes run, so how often the master's state is late is the machine's: what is the
    program's is that it holds exactly then, saying so, and follows otherwise.

    * "the master's state is N ms old": a state stamped N ms before the tick was recorded, and N is past
      teleoperation's watchdog (``WATCHDOG_NS``);
    * "no state from the master device": the device reported none;
    * "after a silent channel: bring the handle back ...": a hold for one of those two came first;
    * "haptic force off": the tick's own haptic command was off (the trainee would not feel the contact).
    """
    from hapticlab.sessions.live.teleop import WATCHDOG_NS

    t_ns = rec.t_ns("/robot/target")
    messages = [m for _, m in rec.topics["/robot/target"]]
    command_on = dict(zip(rec.t_ns("/haptic/command").tolist(), rec.field("/haptic/command", "enabled").tolist()))
    state_ns = rec.t_ns("/haptic/state")
    held = np.zeros(len(t_ns), dtype=bool)
    for k in np.flatnonzero(after):
        mode, reason = messages[k]["mode"], messages[k]["reason"]
        if mode == "following":
            assert reason == "" and command_on[int(t_ns[k])], (k, reason)
            continue
        held[k] = True
        assert mode == "holding", (k, mode)
        if reason == "haptic force off":
            assert not command_on[int(t_ns[k])], k
        elif reason.startswith("the master's state is "):
            age_ms = int(reason.split()[4])
            assert age_ms * 1_000_000 >= WATCHDOG_NS - 500_000, reason
            assert np.any(np.abs(t_ns[k] - age_ms * 1_000_000 - state_ns) <= 500_000), (k, reason)  # that state
        elif reason.startswith("after a silent channel: "):
            before = [messages[j]["reason"] for j in range(k) if messages[j]["mode"] == "holding"]
            assert any(r.startswith(("the master's state", "no state")) for r in before), (k, reason)
        else:
            assert reason == "no state from the master device", (k, reason)
    return held


def test_over_a_real_pty_the_master_emulator_moves_the_robot_and_feels_the_tissue(tmp_path, spawn_process, paced_run):
    """The master emulator in a process of its own, as a device is: in this interpreter, beside a loop that
    keeps a core busy, every blocking call of its thread waits up to the 5 ms GIL switch interval to run
    again, its replies fall 50 ms behind and the session (rightly) declares the device lost."""
    log = tmp_path / "forces.csv"
    master = emulator_process(
        spawn_process,
        "master",
        "--path",
        "press",
        "--radius",
        "0.05",
        "--period",
        "2",
        "--max-force",
        "8",
        "--log-forces",
        str(log),
    )
    port = master.first_line()
    config = teleop_config(f"haptic.port={port.strip()}", "session.realtime=true", duration=7.0)
    result = paced_run(build_session(config), tmp_path / "pty.mcap")
    device_counts = master.finish()
    assert " 0 CRC error(s)" in device_counts, device_counts
    forces = np.loadtxt(log, delimiter=",", skiprows=1)[:, 1:]
    rec = read_recording(result.path)
    t, p, mode, _reason = targets(rec)
    following = np.array(mode) == "following"
    after = t > tour_end(rec) + 0.2
    held = holds_explained(rec, after)  # following at every tick the recording gives no reason not to
    events = [(m["kind"], m["message"]) for _, m in rec.topics["/events"] if m["kind"] != "overrun"]
    assert following[after].any(), (held.sum(), events)
    # the robot went down with the hand, up to 2.5 cm (half the hand's 5 cm)
    assert 0.015 < p[following, 2].max() - p[following, 2].min() <= 0.025 + 1e-9
    state_z = np.array([m["pose"]["p_DoHo_D"][2] for _, m in rec.topics["/haptic/state"]])
    assert state_z.min() < -0.03  # the handle's state, recorded
    # the device received upward forces while the tool was in the tissue, never above the limit
    assert forces[:, 2].max() > 1.0
    assert np.linalg.norm(forces, axis=1).max() <= 4.0 + 1e-6


def test_the_hand_moves_the_tool_along_the_direction_the_force_comes_back_along():
    """The position map uses the force map's frames: R_BD = R_DBᵀ. With B turned 90° about z in D
    (x_B = y_D), a hand moving along +y_D moves the tool along +x_B, and a push on the tool along
    −x_B comes back on the hand along −y_D."""
    from hapticlab.core.frames import matrix_from_rotvec
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.safety import ForceGovernor
    from hapticlab.sessions.live.teleop import Teleoperation
    from hapticlab.sessions.settings import HapticSettings, TeleopSettings

    haptic = HapticSettings(rotation_DB=(0.0, 0.0, math.pi / 2), max_force_rate=1e6)
    R_DB = ForceGovernor(haptic, 1e-3).R_DB
    assert np.allclose(R_DB @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    teleop = Teleoperation(TeleopSettings(enabled=True, scale=0.5, calibration_tilt_deg=0.0), R_DB)

    def pose(t_ns):  # the robot streams its pose (one older than the watchdog's 30 ms holds the robot)
        return PoseSample(t_ns, np.array([0.0, 1.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))

    quat_DH = np.array([1.0, 0.0, 0.0, 0.0])
    first, _ = teleop.step(0, pose(0), DeviceState(0, quat_DH, np.zeros(3)), True)
    later, _events = teleop.step(
        1_000_000_000, pose(1_000_000_000), DeviceState(1_000_000_000, quat_DH, np.array([0.0, 0.02, 0.0])), True
    )
    assert np.allclose(later.p_BoEo_B - first.p_BoEo_B, [0.01, 0.0, 0.0])
    assert np.allclose(later.R_BE, matrix_from_rotvec(np.array([math.pi, 0.0, 0.0])))  # orientation held
    command = ForceGovernor(haptic, 1e-3).command(0, np.array([-2.0, 0.0, 0.0]), np.eye(3))
    assert np.allclose(command.force_D, [0.0, -2.0, 0.0])


def emulator_process(spawn_process, *args: str):
    """``hapticlab emulate ...`` in a process of its own (as a lab runs it), serving for at most 60 s."""
    return spawn_process(hapticlab_command("emulate", *args, "--duration", "60"), f"hapticlab emulate {args[0]}")


def test_a_master_teleoperates_the_emulated_ur_over_rtde_and_feels_its_net_ft(tmp_path, spawn_process, paced_run):
    """Every part on its real wire and in its own process, as in a lab: the master emulator on a pty,
    the Net F/T over RDT and the UR5e over RTDE in `hapticlab emulate lab`, the targets written with
    ur-rtde's RTDEIOInterface to the registers the shipped URScript reads, the emulated arm running
    that script's logic."""
    netft, ur = "127.0.0.96", "127.0.0.97"
    lab = emulator_process(
        spawn_process, "lab", "--session", "teleop-lab-emulated", "--netft", netft, "--ur", ur, "--rate", "500"
    )
    line = lab.first_line()
    assert "following the targets written to its input registers" in line, line
    # the sensor and the loop at 500 Hz: three processes of 1 kHz work each saturate two cores, and the poses and
    # readings then come so late that the force is off on most ticks (the rule itself: tests/core/test_aligner.py)
    # the hand rests while the tour runs (~4 s: it waits for the arm), then goes down 10 cm in 2.5 s and stays:
    # the robot follows at half scale into the tissue 5 mm under its tip, wherever the recording shows it following
    hand = tmp_path / "hand.csv"
    hand.write_text(f"t,x,y,z\n0,0,0,0\n{HAND_PRESS_AT},0,0,0\n{HAND_PRESS_AT + 2.5},0,0,-0.1\n60,0,0,-0.1\n")
    master = emulator_process(spawn_process, "master", "--path", str(hand))
    port = master.first_line()
    config = teleop_config(
        f"haptic.port={port.strip()}",
        f"sensor.address={netft}",
        f"kinematics.address={ur}",
        "session.realtime=true",
        "session.loop_rate_hz=500",
        "sensor.rate_hz=500",
        duration=HAND_PRESS_AT + 3.5,
        preset="teleop-lab-emulated",
    )
    result = paced_run(build_session(config), tmp_path / "ur.mcap")
    device_counts = master.finish()
    lab.finish()
    assert " 0 CRC error(s)" in device_counts and "force command(s)" in device_counts
    rec = read_recording(result.path)
    t, p, mode, reason = targets(rec)
    # following the hand; a hold only ever because a stream was late, at the very ticks the recording shows it:
    # the force went off (a pose or a sensor record late), or the master's state was (the three processes
    # share the machine's cores: how often one is late is the machine's, not the program's)
    t_cal = tour_end(rec)
    after_tour = t > t_cal + 0.2
    held = holds_explained(rec, after_tour)
    assert (np.array(mode)[after_tour] == "following").any(), held.sum()
    assert set(np.array(reason)[after_tour]) <= {"", "haptic force off", "no state from the master device"}
    # the arm itself (its RTDE poses, not our targets) toured, then went down and up with the hand
    t_pose = (rec.t_ns("/kinematics/pose") - rec.t_ns("/robot/target")[0]) * 1e-9
    quat = np.array([m["quat_BE"] for _, m in rec.topics["/kinematics/pose"]])
    p_pose = np.array([m["p_BoEo_B"] for _, m in rec.topics["/kinematics/pose"]])
    tool_axis_B = np.array([matrix_from_quat_wxyz(q)[:, 2] for q in quat])
    tilt = np.degrees(np.arccos(np.clip(tool_axis_B @ tool_axis_B[0], -1.0, 1.0)))
    assert 20 < tilt[t_pose < t_cal].max() < 30  # the 25° calibration tour, on the arm (a servo overshoots a little)
    # then went where the targets sent it (its servo within 3 mm), no further down than the hand's 10 cm at half
    # scale; how far it got is how long it followed (a hold re-anchors the hand), which is the machine's pace
    sent_z, arm_z = p[t > t_cal + 0.5, 2], p_pose[t_pose > t_cal + 0.5, 2]
    assert np.ptp(sent_z) <= 0.05 + 1e-9
    assert abs(np.ptp(arm_z) - np.ptp(sent_z)) < 0.003, (np.ptp(arm_z), np.ptp(sent_z))
    handle_z = rec.field("/haptic/state", "pose.p_DoHo_D")[:, 2]
    assert handle_z.min() < -0.099  # the device's own replies: its handle went 10 cm down
    # the Net F/T felt the tissue: its reading less its reading at rest after the tour (the same orientation,
    # so the same weight and bias) is the contact
    t0 = rec.t_ns("/robot/target")[0]
    t_state = (rec.t_ns("/haptic/state") - t0) * 1e-9
    pressing = t_state[handle_z < -0.0005].min()
    assert pressing > t_cal + 0.5, "the tour outlasted the hand's rest: no reading at rest to subtract"
    force_S, t_wrench = rec.field("/sensor/wrench", "force_S"), rec.t_ns("/sensor/wrench")
    rest = (t_wrench > t0 + (t_cal + 0.3) * 1e9) & (t_wrench < t0 + pressing * 1e9)
    contact_N = np.linalg.norm(force_S - force_S[rest].mean(axis=0), axis=1)
    assert contact_N.max() > 1.0, contact_N.max()  # the tip 3 mm deep at 300 N/m at least
    # the hand felt that contact, less the deadband, within the limit, at every tick the force was on (and had
    # been for 12 ms: the slew-rate limit's 10 ms ramp to 4 N after an off tick is over); from the newest reading
    force_D, enabled = rec.field("/haptic/command", "force_D"), rec.field("/haptic/command", "enabled")
    settled = np.convolve(enabled.astype(float), np.ones(6), mode="full")[: len(enabled)] == 6  # 6 ticks at 500 Hz
    ticks = np.flatnonzero(settled & (rec.t_ns("/haptic/command") > t0 + pressing * 1e9))
    newest = np.searchsorted(t_wrench, rec.t_ns("/haptic/command")[ticks], side="right") - 1
    haptic = config["haptic"]
    expected_N = np.clip(contact_N[newest] - haptic["deadband"], 0.0, haptic["max_force"])
    felt_N = np.linalg.norm(force_D[ticks], axis=1)
    assert (expected_N > 1.0).sum() > 50, (expected_N > 1.0).sum()  # felt in contact, for 0.1 s at least
    error_N = np.abs(felt_N - expected_N)
    assert np.percentile(error_N, 95) < FELT_TOLERANCE_N, np.percentile(error_N, [50, 95, 100])
    assert (force_D[ticks][expected_N > 1.0, 2] > 0).all()  # pushed back up, out of the tissue
    assert np.linalg.norm(force_D, axis=1).max() <= haptic["max_force"] + 1e-9


def test_the_calibration_tour_moves_the_robot_only_while_someone_is_at_the_master():
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.teleop import Teleoperation
    from hapticlab.sessions.settings import TeleopSettings

    teleop = Teleoperation(TeleopSettings(enabled=True, max_angular_speed=1.0, calibration_dwell_s=0.1), np.eye(3))

    def pose(t_ns):  # the robot streams its pose
        return PoseSample(t_ns, np.array([0.0, 1.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))

    present = lambda t_ns: DeviceState(t_ns, np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))  # noqa: E731 (a one-line closure)
    events = []
    for k in range(500):  # 0.5 s with no master: the tour waits where the robot stands
        target, ev = teleop.step(k * 1_000_000, pose(k * 1_000_000), None, False)
        events += ev
        assert target.mode == "calibrating" and target.reason == "no state from the master device"
        assert np.array_equal(target.R_BE, teleop.start[0])
    for k in range(500, 800):  # someone at the master: it turns, at most 1 rad/s
        target, ev = teleop.step(k * 1_000_000, pose(k * 1_000_000), present(k * 1_000_000), False)
        events += ev
    turned = np.degrees(np.linalg.norm(Rotation.from_matrix(target.R_BE @ teleop.start[0].T).as_rotvec()))
    assert 16.0 < turned <= 0.3 * np.degrees(1.0) + 1e-6  # 0.3 s at 1 rad/s (17.2°), on its way to 25°
    assert [e.kind for e in events] == ["teleop_calibrating", "teleop_holding", "teleop_calibrating"]


@pytest.mark.parametrize("glitch", [1e30, 1.5])
def test_a_handle_no_hand_could_hold_stops_the_robot_with_its_reason(glitch):
    """A master reporting its handle 1e30 m (or 1.5 m) from its origin: the robot holds where it is, the
    event says why, and when the handle is back the robot re-engages from where it held (nothing jumps)."""
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.teleop import Teleoperation
    from hapticlab.sessions.settings import TeleopSettings

    teleop = Teleoperation(TeleopSettings(enabled=True, calibration_tilt_deg=0.0, require_haptics=False), np.eye(3))

    def pose(t_ns):  # the robot streams its pose
        return PoseSample(t_ns, np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))

    quat = np.array([1.0, 0.0, 0.0, 0.0])
    ms = 1_000_000
    first, _ = teleop.step(0, pose(0), DeviceState(0, quat, np.zeros(3)), True)
    moved, _ = teleop.step(100 * ms, pose(100 * ms), DeviceState(100 * ms, quat, np.array([0.0, 0.0, 0.004])), True)
    assert moved.mode == "following" and moved.p_BoEo_B[2] > first.p_BoEo_B[2]
    held, events = teleop.step(
        101 * ms, pose(101 * ms), DeviceState(101 * ms, quat, np.array([0.0, 0.0, glitch])), True
    )
    assert held.mode == "holding" and np.array_equal(held.p_BoEo_B, moved.p_BoEo_B)
    assert [e.kind for e in events] == ["teleop_holding"]
    assert f"its handle {glitch:.3g} m from its origin" in events[0].message, events[0].message
    back, events = teleop.step(102 * ms, pose(102 * ms), DeviceState(102 * ms, quat, np.array([0.0, 0.0, 0.004])), True)
    assert back.mode == "following" and np.array_equal(back.p_BoEo_B, moved.p_BoEo_B)
    assert [e.kind for e in events] == ["teleop_following"]


def test_a_silent_master_holds_the_robot_until_the_handle_is_back_where_it_left():
    """The dVRK's watchdog: a master whose state stops changing its stamp holds the robot from the first tick
    it is more than 30 ms old; when it speaks again with the handle 2 cm from where it left, the robot still
    holds (saying why) and follows only once the handle is back within 10 mm, from where it held."""
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.teleop import REENGAGE_M, WATCHDOG_NS, Teleoperation
    from hapticlab.sessions.settings import TeleopSettings

    teleop = Teleoperation(TeleopSettings(enabled=True, calibration_tilt_deg=0.0, require_haptics=False), np.eye(3))
    quat, ms = np.array([1.0, 0.0, 0.0, 0.0]), 1_000_000

    def step(t_ms, state_ms, x):
        pose = PoseSample(t_ms * ms, np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))
        return teleop.step(t_ms * ms, pose, DeviceState(state_ms * ms, quat, np.array([x, 0.0, 0.0])), True)

    for t in range(0, 101):  # following, the hand 1 cm along x by 100 ms
        target, _ = step(t, t, 0.0001 * t)
    assert target.mode == "following"
    left = target.p_BoEo_B.copy()
    modes = []
    for t in range(101, 161):  # the master repeats its state of 100 ms for 60 ms
        target, events = step(t, 100, 0.01)
        modes.append((t, target.mode, target.reason))
    first_hold = next(t for t, mode, _ in modes if mode == "holding")
    assert first_hold == 100 + WATCHDOG_NS // ms + 1  # the first tick past the watchdog
    assert modes[-1][2] == "the master's state is 60 ms old"
    target, events = step(161, 161, 0.03)  # back, 2 cm from where it left
    assert target.mode == "holding" and np.array_equal(target.p_BoEo_B, left)
    assert target.reason.startswith("after a silent channel: bring the handle back to where it left (20 mm away")
    for t in range(162, 200):  # the hand comes back slowly: it follows once within REENGAGE_M
        x = 0.03 - 0.0005 * (t - 161)
        target, events = step(t, t, x)
        if target.mode == "following":
            break
    assert abs(x - 0.01) <= REENGAGE_M and [e.kind for e in events] == ["teleop_following"]
    assert np.array_equal(target.p_BoEo_B, left)  # from where it held: nothing jumps


def test_a_silent_robot_holds_and_a_clutch_press_re_anchors_the_hand():
    """A robot whose newest pose is more than 30 ms old holds the target; the hand has moved on meanwhile, and a
    press of the clutch (the trainee repositioning on purpose) lets it follow again from the new offset."""
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.teleop import Teleoperation
    from hapticlab.sessions.settings import TeleopSettings

    settings = TeleopSettings(enabled=True, calibration_tilt_deg=0.0, require_haptics=False, clutch_button=1)
    teleop = Teleoperation(settings, np.eye(3))
    quat, ms = np.array([1.0, 0.0, 0.0, 0.0]), 1_000_000

    def step(t_ms, pose_ms, x, buttons=0):
        pose = PoseSample(pose_ms * ms, np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))
        return teleop.step(t_ms * ms, pose, DeviceState(t_ms * ms, quat, np.array([x, 0.0, 0.0]), buttons), True)

    for t in range(0, 50):
        target, _ = step(t, t, 0.0)
    target, events = step(81, 50, 0.0)  # the robot silent since 50 ms
    assert target.reason == "no pose from the robot for 31 ms" and [e.kind for e in events] == ["teleop_holding"]
    target, events = step(90, 89, 0.05)  # it speaks again; the hand is 5 cm away
    assert target.mode == "holding" and "or press the clutch" in target.reason
    step(91, 90, 0.05, buttons=0b10)  # clutch pressed ...
    target, events = step(92, 91, 0.05)  # ... and released: following from here
    assert target.mode == "following" and [e.kind for e in events] == ["teleop_following"]
    moved, _ = step(93, 92, 0.051)
    assert moved.p_BoEo_B[0] > target.p_BoEo_B[0]


def test_a_channel_that_goes_silent_while_the_robot_already_holds_still_needs_the_hand_back():
    """The default require_haptics: a silent robot stream zeroes the force first (stale kinematics), so the robot
    is already holding ("haptic force off") when the watchdog trips; the hand-tool correspondence is still the
    last one followed, and the robot waits for the handle to come back to it before following again."""
    from hapticlab.core.types import PoseSample
    from hapticlab.sessions.live.teleop import Teleoperation
    from hapticlab.sessions.settings import TeleopSettings

    teleop = Teleoperation(TeleopSettings(enabled=True, calibration_tilt_deg=0.0), np.eye(3))
    quat, ms = np.array([1.0, 0.0, 0.0, 0.0]), 1_000_000

    def step(t_ms, pose_ms, x, haptic_on):
        pose = PoseSample(pose_ms * ms, np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.4, 0.0, 0.3]))
        return teleop.step(t_ms * ms, pose, DeviceState(t_ms * ms, quat, np.array([x, 0.0, 0.0])), haptic_on)

    for t in range(0, 50):
        target, _ = step(t, t, 0.0, True)
    assert target.mode == "following"
    target, _ = step(50, 49, 0.0, False)  # the force off first (the gate saw the stale poses)
    assert target.reason == "haptic force off"
    target, _ = step(81, 49, 0.01, False)  # then the watchdog: the robot's stream silent for 32 ms
    assert target.reason.startswith("no pose from the robot")
    target, _ = step(120, 119, 0.05, True)  # both back; the hand 5 cm from where the robot last followed it
    assert target.mode == "holding" and target.reason.startswith("after a silent channel")
    target, events = step(121, 120, 0.005, True)  # within 10 mm of it: following, from where it held
    assert target.mode == "following" and [e.kind for e in events] == ["teleop_following"]


def test_a_silent_master_is_one_haptic_disabled_event_not_one_a_tick(scripted):
    _, rec, _ = scripted
    t0 = rec.t_ns("/robot/target")[0]
    silent = [
        m["message"]
        for t, m in rec.topics["/events"]
        if m["kind"] == "haptic_disabled" and 9.0 <= (t - t0) * 1e-9 < 9.2
    ]
    assert len(silent) == 1 and silent[0].startswith("haptic force zeroed: the master's state is "), silent
