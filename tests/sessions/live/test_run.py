"""Sessions end to end: config → plugins → loop → MCAP, and the safety rules on the way."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers import FINAL_ZERO

from hapticlab.core import hookimpl
from hapticlab.core.host.registry import ConfigError, Registry, make_plugin_manager
from hapticlab.plugins.estimators.kalman.options import KalmanOptions
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import read_recording

KALMAN_OPTIONS = len(dataclasses.fields(KalmanOptions))
"""How many options the message says ``kalman`` has (its options record's fields)."""

ALL_TOPICS = {
    "/sensor/wrench",
    "/kinematics/pose",
    "/aligned/sample",
    "/estimator/kalman",
    "/estimator/rls",
    "/haptic/command",
    "/haptic/state",
    "/tf",
    "/events",
}


def loop_commands(rec):
    """The loop's haptic commands, (t_ns array, messages): all but the session's final zero, checked here."""
    *live, (_, last) = rec.topics["/haptic/command"]
    assert last == FINAL_ZERO
    return np.array([t for t, _ in live]), [m for _, m in live]


def demo(*overrides: str, duration: float = 3.0):
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", f"session.duration={duration}", *overrides])
    return config


@pytest.fixture(scope="module")
def demo_recording(tmp_path_factory):
    """A recorded demo: 8 s simulated, with the first indentation at 6 s."""
    path = tmp_path_factory.mktemp("rec") / "demo.mcap"
    result = run_session(build_session(demo(duration=8.0)), out=path)
    return result, read_recording(path)


def test_recorded_demo_reopens_with_every_topic(demo_recording):
    result, rec = demo_recording
    assert set(rec.topics) == ALL_TOPICS
    n = result.samples
    assert n == 8001 and len(rec.topics["/sensor/wrench"]) == n
    assert len(rec.topics["/aligned/sample"]) == n and len(rec.topics["/estimator/kalman"]) == n
    assert len(rec.topics["/estimator/rls"]) == n  # the paper's, beside it on every sample
    assert len(rec.topics["/kinematics/pose"]) == result.poses == 4001
    session = rec.metadata["hapticlab.session"]
    assert (
        '"estimator": {"name": "kalman"' in session["config"]
        and '"shadows": {"rls": {"name": "rls"' in session["config"]
        and "sim" in session["plugins"]
    )
    assert rec.metadata["hapticlab.summary"]["samples"] == str(n)
    # kalman's refused lone samples (held out, not contacts) are counted in the summary as well
    assert result.held_out_samples is not None and result.held_out_samples >= 0
    assert rec.metadata["hapticlab.summary"]["held_out_samples"] == str(result.held_out_samples)
    seq = rec.field("/sensor/wrench", "seq")
    assert np.array_equal(seq, np.arange(n))  # nothing dropped


def test_the_flange_is_recorded_for_foxglove_s_3d_panel_at_50_hz(demo_recording):
    _, rec = demo_recording
    poses = dict(rec.topics["/kinematics/pose"])
    tf = rec.topics["/tf"]
    assert len(tf) == 401  # 0 to 8 s at 50 Hz, both ends: a pose every 2 ms, one in ten
    assert np.all(np.diff([t for t, _ in tf]) == 20_000_000)
    offset = int(rec.meta("hapticlab.session", "clock_offset_ns"))  # its stamp: Unix time, as the log times
    for t, m in tf[::50]:
        pose = poses[t]  # the pose of that instant, base → flange, quaternion as x y z w
        assert (m["parent_frame_id"], m["child_frame_id"]) == ("base", "flange")
        assert m["timestamp"] == {"sec": (t + offset) // 10**9, "nsec": (t + offset) % 10**9}
        w, x, y, z = pose["quat_BE"]
        assert m["rotation"] == {"x": x, "y": y, "z": z, "w": w}
        assert [m["translation"][k] for k in "xyz"] == pose["p_BoEo_B"]


def test_demo_separates_the_indentation_from_the_tool_weight(demo_recording):
    _, rec = demo_recording
    t = (rec.t_ns("/estimator/rls") - rec.t_ns("/estimator/rls")[0]) * 1e-9
    force = rec.field("/estimator/rls", "contact_force_S")
    contact = rec.field("/estimator/rls", "contact").astype(bool)
    free = (t > 2.0) & (t < 5.9)
    # away from contact only noise and unmodelled inertia remain (sensor noise 0.12 N per axis)
    assert np.sqrt(np.mean(force[free] ** 2, axis=0)).max() < 0.2
    assert not contact[free].any()
    pressing = (t > 6.4) & (t < 7.1)  # the 3 N indentation's plateau
    assert contact[pressing].all()
    assert np.abs(np.linalg.norm(force[pressing], axis=1) - 3.0).mean() < 0.25


def test_haptics_wait_for_convergence_and_are_clamped(demo_recording):
    _result, rec = demo_recording
    enabled = rec.field("/haptic/command", "enabled").astype(bool)
    force_D = rec.field("/haptic/command", "force_D")
    t_cmd = rec.t_ns("/haptic/command")
    converged_at = next(t for t, m in rec.topics["/events"] if m["kind"] == "converged")
    assert not enabled[t_cmd < converged_at].any() and enabled[-100:-1].all()
    # the session ends with a zero command, sent and recorded
    assert rec.topics["/haptic/command"][-1][1] == FINAL_ZERO
    assert np.all(force_D[~enabled] == 0.0)
    # each command records the tool-tissue force it was made from: the primary's |contact force| at its source
    estimates = rec.estimates("kalman")
    at = {int(t): float(np.linalg.norm(f)) for t, f in zip(estimates.t_ns, estimates.contact_force_S, strict=True)}
    made_from = [(m["source_t_ns"], m["contact_force_N"]) for _, m in rec.topics["/haptic/command"] if m["enabled"]]
    assert made_from and all(f == pytest.approx(at[s], rel=1e-12) for s, f in made_from)
    # each force says which sample it was estimated from: one in this tick (not stale), an estimate's stamp
    source = np.array([m["source_t_ns"] for _, m in rec.topics["/haptic/command"]], dtype=object)
    assert all(s is None for s in source[~enabled])
    age_ns = t_cmd[enabled] - source[enabled].astype(np.int64)
    assert age_ns.min() >= 0 and age_ns.max() < 1_000_000  # non-realtime: the tick's own sample
    assert set(source[enabled].astype(np.int64)) <= set(rec.t_ns("/estimator/rls").tolist())
    assert np.linalg.norm(force_D, axis=1).max() <= 4.0 + 1e-9
    step = np.linalg.norm(np.diff(force_D[enabled], axis=0), axis=1)
    assert step.max() <= 400.0 * 1e-3 + 1e-9  # max_force_rate · device period
    kinds = [m["kind"] for _, m in rec.topics["/events"]]
    assert kinds[:2] == ["session_start", "haptic_disabled"] and kinds[-1] == "session_end"


def test_estimator_swap_from_overrides(tmp_path):
    result = run_session(build_session(demo("estimator.name=batch", duration=1.0)), out=tmp_path / "b.mcap")
    rec = read_recording(result.path)
    assert "/estimator/batch" in rec.topics and "/estimator/kalman" not in rec.topics
    assert "/estimator/rls" in rec.topics  # the preset's shadow still beside it
    assert result.held_out_samples is None  # batch holds nothing out


class FlakyDevice:
    """A master device that is lost after some commands (raises from send)."""

    def __init__(self, rate_hz: float = 1000.0, fail_after: int = 1500):
        self.rate_hz, self.fail_after, self.sent = rate_hz, fail_after, 0

    def open(self): ...
    def close(self): ...
    def state(self):
        return None

    def send(self, command):
        self.sent += 1
        if self.sent > self.fail_after:
            raise OSError("USB device disconnected")


class InterruptingSensor:
    """Wraps the simulated sensor and raises Ctrl-C after some reads."""

    def __init__(self, rate_hz: float = 1000.0, stop_after: int = 700, world=None):
        from hapticlab.plugins.sensors.sim import SimSensor

        self.inner, self.stop_after, self.reads = SimSensor(rate_hz, world=world), stop_after, 0
        self.rate_hz = rate_hz

    def open(self, t0_ns):
        self.inner.open(t0_ns)

    def close(self):
        self.inner.close()

    def read(self, until_ns):
        self.reads += 1
        if self.reads > self.stop_after:
            raise KeyboardInterrupt
        return self.inner.read(until_ns)


class GappyKinematics:
    """The simulated robot, silent between 3.0 s and 3.2 s."""

    def __init__(self, rate_hz: float = 500.0, world=None):
        from hapticlab.plugins.kinematics.sim import SimKinematics

        self.inner, self.rate_hz, self.t0 = SimKinematics(rate_hz, world=world), rate_hz, 0

    def open(self, t0_ns):
        self.t0 = t0_ns
        self.inner.open(t0_ns)

    def close(self):
        self.inner.close()

    def read(self, until_ns):
        poses = self.inner.read(until_ns)
        return [p for p in poses if not 3.0e9 < p.t_ns - self.t0 < 3.2e9]


class TestPlugins:
    @hookimpl
    def register_haptic_outputs(self, register):
        register("flaky", FlakyDevice)

    @hookimpl
    def register_sensors(self, register):
        register("interrupting", InterruptingSensor)

    @hookimpl
    def register_kinematics(self, register):
        register("gappy", GappyKinematics)


@pytest.fixture
def registry():
    pm = make_plugin_manager(load_entry_points=False)
    pm.register(TestPlugins(), name="tests")
    return Registry(pm)


def test_lost_device_zeroes_force_and_is_recorded(tmp_path, registry):
    config = demo("haptic.name=flaky", "haptic.fail_after=1500", duration=2.0)
    result = run_session(build_session(config, registry), out=tmp_path / "lost.mcap")
    rec = read_recording(result.path)
    messages = [m for _, m in rec.topics["/haptic/command"]]
    after = messages[1500:]
    assert after and all(not m["enabled"] and m["force_D"] == [0.0, 0.0, 0.0] for m in after)
    assert after[0]["reason"] == "device error: USB device disconnected"
    assert any("device error" in m["message"] for _, m in rec.topics["/events"])
    assert result.samples == 2001  # the session carried on recording


def test_stale_kinematics_zero_the_force(tmp_path, registry):
    # the robot stops reporting poses from 3.0 s to 3.2 s (the force is on from ~2.2 s)
    config = demo("kinematics.name=gappy", duration=3.5)
    result = run_session(build_session(config, registry), out=tmp_path / "stale.mcap")
    rec = read_recording(result.path)
    t = (rec.t_ns("/aligned/sample") - rec.t_ns("/aligned/sample")[0]) * 1e-9
    stale = rec.field("/aligned/sample", "stale").astype(bool)
    # one kinematics period (2 ms) of extrapolation is allowed, not more
    assert np.array_equal(stale, (t > 3.0 + 0.002 + 1e-9) & (t < 3.2))
    t_cmd, commands = loop_commands(rec)
    t_cmd = (t_cmd - rec.t_ns("/aligned/sample")[0]) * 1e-9
    enabled = np.array([m["enabled"] for m in commands])
    assert enabled[(t_cmd > 2.5) & (t_cmd < 3.0)].all()
    during = [m for tc, m in zip(t_cmd, commands) if 3.003 < tc < 3.2]
    assert during and all(m["reason"] == "stale kinematics" and m["force_D"] == [0.0] * 3 for m in during)
    assert enabled[t_cmd > 3.21].all()  # back on once poses return
    # stale samples never reach the estimator
    assert len(rec.topics["/estimator/rls"]) == int((~stale).sum())


def test_ctrl_c_finishes_the_file_cleanly(tmp_path, registry):
    config = demo("sensor.name=interrupting", "sensor.stop_after=700", duration=5.0)
    result = run_session(build_session(config, registry), out=tmp_path / "ctrlc.mcap")
    assert result.interrupted and result.samples == 701  # samples at 0, 1, ..., 700 ms
    rec = read_recording(result.path)  # a valid, complete MCAP (summary, footer)
    assert len(rec.topics["/sensor/wrench"]) == 701
    assert rec.topics["/events"][-1][1]["message"] == "interrupted (Ctrl-C)"
    assert rec.metadata["hapticlab.summary"]["interrupted"] == "true"


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("estimator.name=kalmann", r"^estimator.name: unknown estimator 'kalmann'; available: batch, kalman, rls$"),
        (
            "shadows.rls.force_treshold=2",
            r"^shadows.rls.force_treshold: unknown option; did you mean force_threshold\?"
            r"; known options: .*force_threshold",
        ),
        ("shadows.rls.force_threshold=high", r"^shadows.rls.force_threshold: must be a number, got 'high'$"),
        (
            "estimator.noise_forse=0.1",
            r"^estimator.noise_forse: unknown option; did you mean noise_force\?; known "
            rf"options: {KALMAN_OPTIONS}, documented in "
            r"hapticlab.plugins.estimators.kalman.options.KalmanOptions$",
        ),
        ("session.duration=soon", r"^session.duration: must be a finite number > 0 and <= 86400 \(s\), got 'soon'$"),
        ("haptic.max_force=[1, 2]", r"^haptic.max_force: must be a finite number > 0 \(N\), got \[1, 2\]$"),
        ("world.tool.mass=heavy", r"^world.tool.mass: must be a finite number > 0 \(kg\), got 'heavy'$"),
        ("sensor.rate_hz=true", r"^sensor.rate_hz: must be a number, got True$"),
    ],
)
def test_config_errors_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        build_session(demo(override))


def test_unknown_table_and_missing_name():
    with pytest.raises(ConfigError, match=r"^sensr.rate_hz: unknown table 'sensr'"):
        apply_overrides({}, ["sensr.rate_hz=1"])
    config = demo()
    config["estimatr"] = {"name": "rls"}
    with pytest.raises(ConfigError, match=r"^estimatr: unknown table; tables: "):
        build_session(config)
    config = demo()
    del config["estimator"]["name"]
    with pytest.raises(ConfigError, match=r"^estimator.name: missing"):
        build_session(config)


def test_sensor_slower_than_the_loop_never_enables_early(tmp_path):
    # a 500 Hz sensor in a 1 kHz loop: every other tick has no new sample
    result = run_session(build_session(demo("sensor.rate_hz=500.0", duration=4.0)), out=tmp_path / "slow.mcap")
    rec = read_recording(result.path)
    t_cmd, commands = loop_commands(rec)
    enabled = np.array([m["enabled"] for m in commands])
    known = next(t for t, m in rec.topics["/events"] if m["kind"] == "parameters_known")
    assert not enabled[t_cmd < known].any() and enabled[t_cmd > known].all()
    toggles = [m["message"] for _, m in rec.topics["/events"] if m["kind"].startswith("haptic_")]
    # off until converged (and, when the first convergence comes before the parameters are known, off until
    # identified: which comes first depends on the data), then on, once and for good
    assert toggles[0] == "haptic force zeroed: estimator not converged" and toggles[-1] == "haptic force on"
    assert toggles.count("haptic force on") == 1
    assert set(toggles[1:-1]) <= {"haptic force zeroed: parameters not yet identified"}


class SaturatingSensor(InterruptingSensor):
    """The simulated sensor, reporting saturation between 2.5 s and 2.6 s."""

    def read(self, until_ns):
        from dataclasses import replace

        from hapticlab.core.types import STATUS_SATURATED

        samples = self.inner.read(until_ns)
        t0 = self.inner_t0
        return [replace(s, status=STATUS_SATURATED) if 2.5e9 <= s.t_ns - t0 < 2.6e9 else s for s in samples]

    def open(self, t0_ns):
        self.inner_t0 = t0_ns
        self.inner.open(t0_ns)


def test_saturated_samples_zero_the_force(tmp_path):
    from hapticlab.core.host.registry import Registry, make_plugin_manager

    class Plug:
        @hookimpl
        def register_sensors(self, register):
            register("saturating", SaturatingSensor)

    pm = make_plugin_manager(load_entry_points=False)
    pm.register(Plug(), name="saturating")
    config = demo("sensor.name=saturating", duration=3.0)
    result = run_session(build_session(config, Registry(pm)), out=tmp_path / "sat.mcap")
    rec = read_recording(result.path)
    t0 = rec.t_ns("/sensor/wrench")[0]
    t_cmd, commands = loop_commands(rec)
    t_cmd = (t_cmd - t0) * 1e-9
    during = [m for t, m in zip(t_cmd, commands) if 2.501 < t < 2.6]
    assert during and all(m["reason"] == "sensor saturated or in error" for m in during)
    assert all(m["enabled"] for t, m in zip(t_cmd, commands) if t > 2.61)
    # saturated samples are recorded but never reach the estimator
    assert len(rec.topics["/estimator/rls"]) == result.samples - 100


def test_switching_estimator_drops_the_presets_options_for_the_old_one():
    config = demo("estimator.name=kalman", "estimator.noise_force=0.1", duration=0.5)
    assert config["estimator"] == {"name": "kalman", "noise_force": 0.1}
    session = build_session(config)
    assert session.estimator_name == "kalman" and session.resolved_config["estimator"]["noise_force"] == 0.1
    # naming the plugin the file already names changes nothing
    config = demo("haptic.name=null")
    assert config["haptic"]["max_force_rate"] == 400.0


def test_naming_the_presets_shadow_as_the_estimator_promotes_it():
    """The presets run kalman with rls beside it; estimator.name=rls makes that rls the primary, with its options,
    and it no longer runs beside itself; another name leaves the shadow beside the new primary."""
    config = demo("estimator.name=rls")
    assert config["estimator"] == {"name": "rls", "force_threshold": 1.0, "torque_threshold": 0.1}
    assert "shadows" not in config
    session = build_session(config)
    assert session.estimator_name == "rls" and not session.shadows
    config = demo("estimator.name=batch")
    assert config["estimator"] == {"name": "batch"} and config["shadows"]["rls"]["force_threshold"] == 1.0


def test_a_payload_change_holds_the_haptic_force_at_zero(tmp_path, long_session):
    """kalman recognises a 100 g mass hung for good; the loop then holds the force at zero for 1 s."""
    config = demo("estimator.name=kalman", duration=12.0)
    config["world"]["contacts"] = [{"kind": "hanging_mass", "start": 9.0, "duration": 1e9, "mass": 0.1}]
    result = long_session(build_session(config), out=tmp_path / "payload.mcap")
    rec = read_recording(result.path)
    t_event = next(t for t, m in rec.topics["/events"] if m["kind"] == "payload_change")
    t_cmd, commands = loop_commands(rec)
    held = (t_cmd > t_event) & (t_cmd < t_event + 0.9e9)
    assert held.any() and not any(commands[k]["enabled"] for k in np.flatnonzero(held))
    assert all(commands[k]["reason"].startswith("payload change") for k in np.flatnonzero(held))
    assert commands[-1]["enabled"]  # and trusted again afterwards


def test_a_known_mount_turns_the_haptic_force_into_the_base_frame(tmp_path):
    """With a mount R_SE the contact force in S reaches the device through R_BS = R_BE·R_ES, not R_BE."""
    from hapticlab.core.frames import matrix_from_rotvec

    mount = [0.0, 0.0, 0.5]
    config = demo("estimator.name=kalman", duration=8.0)
    config["estimator"]["mount_rotation_SE"] = mount
    config["world"]["sensor"] = {"mount_rotation": mount}
    result = run_session(build_session(config), out=tmp_path / "mount.mcap")
    rec = read_recording(result.path)
    t_cmd, force_D = rec.t_ns("/haptic/command"), rec.field("/haptic/command", "force_D")
    enabled = rec.field("/haptic/command", "enabled").astype(bool)
    # during the 3 N indentation (6.0–7.5 s, along the tool axis) the device force is its base-frame image
    t0 = rec.t_ns("/sensor/wrench")[0]
    press = enabled & (t_cmd - t0 > 6.5e9) & (t_cmd - t0 < 7.0e9)
    assert press.sum() > 100
    sim = build_session(config).contexts["world"]  # the same world: the true contact force in B at those times
    true_B = []
    for t in (t_cmd[press] - t0) * 1e-9:
        w = sim.wrench(np.array([t]), noise=False)
        R_BS = w["R_EB"][0].T @ matrix_from_rotvec(mount).T
        true_B.append(R_BS @ w["contact_force_S"][0])
    error = np.linalg.norm(force_D[press] - np.array(true_B), axis=1)
    assert np.median(error) < 0.3  # (ignoring the mount would tilt a 3 N force by 29°: 1.5 N)


def test_each_pose_is_recorded_with_its_age_when_read(demo_recording):
    """The kinematics' delay is in the recording: the simulated arm's poses are read the tick they are due."""
    _, rec = demo_recording
    ages = np.array([m["age_ns"] for _, m in rec.topics["/kinematics/pose"]])
    assert len(ages) == 4001 and ages.min() >= 0 and ages.max() <= 1_000_000  # a 1 ms tick reads each pose due
