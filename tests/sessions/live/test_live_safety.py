"""The haptic path trusts nothing: injected faults never put a made-up force on the hand; signals end sessions
cleanly."""

from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np
import pytest
from helpers import FINAL_ZERO
from processes import PROCESS_START_S

from hapticlab.core.host.registry import ConfigError
from hapticlab.sessions.bench.faults import FAULT_START_S, FAULTS, made_up_force, measure, session
from hapticlab.sessions.cli.run import weight_identified
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.live.safety import ForceGovernor
from hapticlab.sessions.recording import read_recording
from hapticlab.sessions.settings import HapticSettings


@pytest.fixture(scope="module")
def clean():
    """The demo session (7 s, rls) without a fault: the reference every fault is measured against."""
    return session("rls", None)


@pytest.mark.parametrize(
    "label",
    [
        "sensor spike +1000 N, 20 ms",
        "sensor NaN, 200 ms",
        "sensor saturated, 200 ms",
        "sensor dropout, 500 ms",
        "kinematics frozen, 2 s",
        "kinematics dropout, 500 ms",
    ],
)
def test_a_fault_is_caught_within_100_ms_and_makes_up_less_than_half_a_newton(clean, label):
    r = measure("rls", clean, FAULTS[label])
    print(f"\n{label}: {r}")
    assert r["detected_after_s"] is not None and r["detected_after_s"] <= 0.1
    assert r["zero_after_detection_s"] is not None and r["zero_after_detection_s"] <= 0.05
    assert r["made_up_force_N"] <= 0.5
    assert r["event"] is not None and r["event"].startswith("fault: ")


def test_poses_late_at_once_jump_and_are_caught_at_the_first_late_pose(clean):
    r = measure("rls", clean, FAULTS["kinematics 200 ms late, 2 s"])
    print(f"\nkinematics 200 ms late: {r}")
    assert r["detected_after_s"] is not None and r["detected_after_s"] <= 0.01
    assert r["made_up_force_N"] <= 0.5
    assert r["event"].startswith("fault: kinematics jumped (turned")


def test_a_lag_that_builds_up_is_caught_from_the_motion_and_held_until_it_is_gone(clean):
    """No jump gives it away: the residual's torque shows it acting where nothing touches the tool (at its
    centre of gravity: the weight model off) before the lag watch has found the lag from its correlation with
    the motion, and it is not taken for a bias (no re-identification); the force stays off (the estimator would
    otherwise learn the lag and hide it) until the fault ends."""
    label = "kinematics late by 0→200 ms over 0.5 s, 2 s"
    r = measure("rls", clean, FAULTS[label])
    print(f"\n{label}: {r}")
    # the lag passes the 50 ms limit 0.125 s into the ramp; resolving it from the motion takes turning:
    # measured here 0.38 s after the ramp's start (0.25 s after the limit)
    assert r["detected_after_s"] is not None and r["detected_after_s"] <= 0.45
    assert r["made_up_force_N"] <= 0.5
    assert "acts where nothing touches the tool" in r["event"] and "the weight model is off" in r["event"]
    fault = dict(FAULTS[label])
    _, _, _, events, _ = session("rls", fault, fault.pop("session_s", 7.0))
    assert not [e for e in events if e.kind == "bias_step"]
    assert [e for e in events if e.message.startswith("kinematics out of step with the sensor")]


@pytest.mark.parametrize("label", ["sensor bias step +2 N", "sensor bias step +2 N during a contact"])
def test_a_sudden_step_holds_the_force_until_the_motion_shows_it_is_the_sensor_s(clean, label):
    """2 N in one sample is faster than soft tissue pushes, slower than a glitch: the force goes off at the
    step (no contact rendered meanwhile), and once the tool has turned the residual is seen to keep its
    direction in the sensor frame: a bias step, re-identified. In a contact, that is told once it ends."""
    fault = dict(FAULTS[label])
    duration_s = fault.pop("session_s", 7.0)
    start_s = fault.get("start", FAULT_START_S)
    t, force, _messages, events, t0 = session("rls", fault, duration_s)
    first = next(e for e in events if (e.t_ns - t0) * 1e-9 >= start_s and e.kind == "fault")
    assert first.message.startswith("sudden force step (2.")
    assert (first.t_ns - t0) * 1e-9 - start_s <= 0.002
    step = next(e for e in events if e.kind == "bias_step")
    t_step = (step.t_ns - t0) * 1e-9
    assert "kept its direction in the sensor frame while the tool turned" in step.message
    assert t_step - start_s <= (1.0 if label == "sensor bias step +2 N" else 2.0)  # the contact ends 7.5 s
    held = (t >= start_s + 0.002) & (t <= t_step)
    assert np.all(np.linalg.norm(force[held], axis=1) == 0.0)
    assert not [e for e in events if "kinematics" in e.message]  # a sensor fault is never the kinematics'


def test_a_drifting_bias_is_the_sensor_s_and_keeps_the_force_off_while_it_drifts(long_session):  # (12 s: slow)
    """3 N over 6 s (0.5 N/s, faster than kalman's bias walk follows): held from its torque (none: it acts at
    the sensor, where nothing touches the tool) before the motion shows it in the sensor frame, never blamed on
    the kinematics, and the force stays off while the residual has not settled (the drift during an
    indentation, unseen there, shows after it)."""
    label = "sensor bias ramp +3 N over 6 s, then held"
    fault = dict(FAULTS[label])
    duration_s = fault.pop("session_s")
    t_ref, force_ref, *_ = session("kalman", None, duration_s)
    t, force, messages, events, t0 = session("kalman", fault, duration_s)
    assert not [e for e in events if "kinematics" in e.message]
    first = next(e for e in events if e.kind == "fault" and (e.t_ns - t0) * 1e-9 >= FAULT_START_S)
    assert "acts where nothing touches the tool" in first.message  # its torque: none, before the tool turns
    step = next(e for e in events if e.kind == "bias_step")
    assert "kept its direction in the sensor frame" in step.message
    n = min(len(t), len(t_ref))
    after = t[:n] >= FAULT_START_S
    assert made_up_force(force[:n][after], force_ref[:n][after]).max() <= 0.5
    settling = [m["reason"] for m in messages if "the residual to settle" in m["reason"]]
    assert settling  # held after re-identifying, while the drift went on


def test_a_jump_that_stays_during_a_contact_is_not_re_identified_while_the_contact_hides_it():
    """+5 N for 1 s from 6.5 s, inside the 6-7.5 s indentation: the jump is held out, and when it stays the
    force is held until the motion tells (no re-identification in the contact: kalman re-opened its bias there,
    took the contact in with the step, and pushed 2.9 N at the hand when the indentation ended)."""
    label = "sensor offset +5 N for 1 s, during a contact"
    fault = dict(FAULTS[label])
    duration_s = fault.pop("session_s")
    clean = session("kalman", None, duration_s)
    r = measure("kalman", clean, FAULTS[label])
    print(f"\n{label}: {r}")
    assert r["made_up_force_N"] <= 0.5
    _, _, _, events, t0 = session("kalman", fault, duration_s)
    assert not [e for e in events if e.kind in ("bias_step", "weight_step") and (e.t_ns - t0) * 1e-9 < 7.5]


@pytest.mark.parametrize("estimator", ["rls", "kalman"])
def test_a_tool_lifted_off_the_tissue_it_started_on_is_not_pushed_back_at_the_hand(estimator):
    """The session starts with the tool resting on tissue (2 N straight up: to the estimator, a lighter
    tool); at 5 s it is lifted off at once. The missing support looks like a 2 N pull: held from the lift
    (a sudden step), never rendered (2.0 N reached the hand before). kalman then tells a weight change (its
    payload test). rls, Algorithm 1 as printed, fits the support's moment into its torque stage so poorly
    that the torque residual passes τ_th before the lift (a contact, rightly: the tool rests on tissue), so the
    lift is a step begun in a contact: not told, held to the end (the reason says so; a re-arm releases it)."""
    label = "session started resting on tissue (2 N up), lifted off at 5 s"
    clean = session(estimator, None)
    r = measure(estimator, clean, FAULTS[label])
    print(f"\n{label}: {r}")
    assert r["made_up_force_N"] <= 0.5
    assert r["detected_after_s"] is not None and r["detected_after_s"] <= 0.002
    _, force, messages, events, _ = session(estimator, FAULTS[label])
    if estimator == "kalman":
        assert {"payload_change", "weight_step"} & {e.kind for e in events}
    else:
        lifted = next(k for k, m in enumerate(messages) if m["reason"].startswith("sudden force step"))
        assert not np.any(force[lifted:])
        assert all(m["reason"].startswith("sudden force step") for m in messages[lifted:])
        assert not {"contact_confirmed", "weight_step", "bias_step"} & {e.kind for e in events}


@pytest.mark.parametrize("estimator", ["rls", "kalman"])
def test_after_a_bias_step_the_estimator_re_identifies_and_the_force_comes_back_right(estimator):
    # 9.4 s: after a bias step the force waits for a settled residual, which the 6-7.5 s indentation delays
    t, force, _messages, events, t0 = session(estimator, FAULTS["sensor bias step +2 N"], 9.4)
    kinds = [e.kind for e in events]
    assert "bias_step" in kinds and "bias_reidentified" in kinds and "bias_settled" in kinds
    back = next(e for e in events if e.kind == "bias_reidentified")
    assert (back.t_ns - t0) * 1e-9 - FAULT_START_S < 2.5
    settled = next(e for e in events if e.kind == "bias_settled")
    t_back = (settled.t_ns - t0) * 1e-9
    # once back on, the device force is the contact's again: the clean run's, not the 2 N step
    t_ref, force_ref, *_ = session(estimator, None, 9.4)
    n = min(len(t), len(t_ref))
    later = t[:n] > t_back + 0.2
    assert later.any() and made_up_force(force[:n][later], force_ref[:n][later]).max() < 0.5


def test_no_fault_is_seen_in_clean_sessions(long_session):
    """Demo sessions with indentations while the tool turns, three seeds and estimators: nothing is called a fault."""
    for estimator, seed in (("rls", 2), ("kalman", 3), ("batch", 5)):
        config, _ = load_config("demo")
        config = apply_overrides(
            config,
            ["session.realtime=false", "session.duration=15", f"world.seed={seed}", f"estimator.name={estimator}"],
        )
        events = session_events(config, long_session)
        assert not [e for e in events if e.kind in ("fault", "bias_step")], (estimator, seed)


def test_a_bias_an_estimator_took_from_a_contact_is_caught_once_the_contact_is_gone(long_session, tmp_path):
    """batch (no bias walk, no re-identification) takes part of the demo's second indentation (9.5-11 s) into its
    bias: after it, with nothing touching, it renders 0.55-0.8 N (measured before the drift watch). That residual
    keeps its direction in the sensor frame while the tool turns: caught before the next touch (12.5 s), and
    batch cannot re-identify, so the force latches off."""
    config, _ = load_config("demo")
    config = apply_overrides(
        config, ["session.realtime=false", "session.duration=15", "world.seed=4", "estimator.name=batch"]
    )
    result = long_session(build_session(config), out=tmp_path / "batch.mcap")
    t0 = result.events[0].t_ns
    (step,) = [e for e in result.events if e.kind == "bias_step"]
    t_step = (step.t_ns - t0) * 1e-9
    assert 11.0 < t_step < 12.5 and "kept its direction in the sensor frame" in step.message
    rec = read_recording(result.path)
    t = (rec.t_ns("/haptic/command") - t0) * 1e-9
    force = np.array([np.linalg.norm(m["force_D"]) for _, m in rec.topics["/haptic/command"]])
    untouched = (t > 11.2) & (t < t_step)  # the indentation's gone: all of this force was made up
    assert untouched.any() and force[untouched].mean() > 0.4
    assert np.all(force[(t > t_step) & (t < 14.9)] == 0.0)
    assert "haptic_latched" in [e.kind for e in result.events]


def session_events(config, run=run_session):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        return run(build_session(config), out=Path(folder) / "clean.mcap").events


def test_made_up_force_counts_what_the_true_force_cannot_explain():
    truth = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    force = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.3, 0.4], [1.0, 1.0, 0.0]])
    assert np.allclose(made_up_force(force, truth), [0.0, 0.0, 0.5, 1.0])


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (
            "session.stale_timeout=100",
            r"^session.stale_timeout: must be a finite number >= 0 and <= 1 \(s; 0: automatic\), got 100$",
        ),
        (
            "session.loop_rate_hz=3e9",
            r"^session.loop_rate_hz: must be a finite number >= 100 and <= 10000 \(Hz\), got 3000000000.0$",
        ),
        ("session.duration=-5", r"^session.duration: must be a finite number > 0 and <= 86400 \(s\), got -5$"),
        ("session.duration=inf", r"^session.duration: must be a finite number > 0 and <= 86400 \(s\), got inf$"),
        ("sensor.rate_hz=1e9", r"^sensor.rate_hz: must be a finite number >= 1 and <= 100000 Hz"),
        ("kinematics.rate_hz=-1", r"^kinematics.rate_hz: must be a finite number >= 1 and <= 10000 Hz"),
        (
            "world.faults=[{kind = 'sensor_smoke', start = 1.0}]",
            r"^world.faults\[0\].kind: must be 'sensor_spike', .*, got 'sensor_smoke'$",
        ),
        ("world.faults=[{kind = 'sensor_nan'}]", r"^world.faults\[0\].start: missing"),
    ],
)
def test_settings_that_make_no_physical_sense_are_refused(override, message):
    config, _ = load_config("demo")
    with pytest.raises(ConfigError, match=message):
        build_session(apply_overrides(config, [override]))


def test_duration_on_the_command_line_is_checked(capsys):
    from hapticlab.sessions.cli import main

    for value, why in (
        ("inf", "must be a finite number > 0 and <= 86400 (s), got inf"),
        ("-5", "must be a finite number > 0 and <= 86400 (s), got -5.0"),
    ):
        assert main(["run", "--duration", value]) == 2
        assert f"--duration: {why}" in capsys.readouterr().err


def test_the_governor_checks_its_output():
    governor = ForceGovernor(HapticSettings(), period_s=1e-3)
    huge = np.array([1.7e308, 1.7e308, 0.0])  # finite, but the rotation overflows
    R = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])
    command = governor.command(0, huge, R)
    assert not command.enabled and np.array_equal(command.force_D, np.zeros(3))
    assert command.reason == "non-finite force after the mapping"
    # after a zero the force ramps up again at the slew limit, never jumps
    steps = [governor.command(k, np.array([3.0, 0.0, 0.0]), np.eye(3)).force_D for k in range(1, 12)]
    assert np.linalg.norm(steps[0]) <= 0.4 + 1e-12
    assert np.max(np.linalg.norm(np.diff(steps, axis=0), axis=1)) <= 0.4 + 1e-12


def run_in_subprocess(spawn_process, tmp_path, *extra):
    """``hapticlab run`` (the demo, paced, 30 s) in a process of its own, once its loop is ticking: (process, out)."""
    out = tmp_path / "signalled.mcap"
    code = (
        "import sys; from hapticlab.sessions.cli import main; "
        f"sys.exit(main(['run', '--duration', '30', '--out', {str(out)!r}, *{list(extra)!r}]))"
    )
    proc = spawn_process([sys.executable, "-c", code], "hapticlab run", text=False)
    deadline = time.monotonic() + PROCESS_START_S  # against hanging, not a timing assertion
    while not (out.exists() and out.stat().st_size > 0):
        assert time.monotonic() < deadline and proc.poll() is None, "hapticlab run never started its recording"
        time.sleep(0.1)
    time.sleep(1.0)
    return proc, out


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_end_a_session_like_ctrl_c(tmp_path, signum, spawn_process):
    proc, out = run_in_subprocess(spawn_process, tmp_path)
    proc.send_signal(signum)
    assert proc.wait_for_exit() == 0
    rec = read_recording(out)  # complete: footer and summary
    assert rec.metadata["hapticlab.summary"]["interrupted"] == "true"
    assert rec.topics["/events"][-1][1]["message"] == f"interrupted ({signal.Signals(signum).name})"
    last = rec.topics["/haptic/command"][-1][1]
    assert last == FINAL_ZERO


def test_a_second_ctrl_c_still_leaves_a_readable_file(tmp_path, spawn_process):
    proc, out = run_in_subprocess(spawn_process, tmp_path)
    proc.send_signal(signal.SIGINT)
    for _ in range(20):  # keep pressing while it ends
        time.sleep(0.005)
        if proc.poll() is not None:
            break
        os.kill(proc.pid, signal.SIGINT)
    proc.wait_for_exit()
    rec = read_recording(out)
    assert rec.metadata["hapticlab.summary"]["interrupted"] == "true"
    assert rec.topics["/haptic/command"][-1][1]["force_D"] == [0.0] * 3


def test_a_tool_turned_about_one_axis_only_is_told_what_the_motion_cannot_identify(tmp_path):
    """The demo's estimator (kalman) while the tool turns about its own axis only (horizontal, about B's x):
    the weight's x component maps to one sensor direction at every roll, like the bias, so no motion of this
    kind identifies it. The estimator says so (a not_identifiable event naming x; NaN for it in its params),
    the force stays zero all along, and the reason the haptic command gives names it and how to move: a warm-up,
    not a fault. (The estimator's flag is up at the poses it knows, so the reason is soon the gate's own: the
    parameters, gravity's std as identified, not yet known to ready_force_std.)"""
    config = apply_overrides(
        load_config("demo")[0],
        [
            "session.realtime=false",
            'world.motion={script="axial_rotation", speed_deg_s=30.0, turns=2.0, ramp_s=1.0, start_s=0.5}',
        ],
    )
    result = run_session(build_session(config), out=tmp_path / "axial.mcap", duration=6.0)
    said = [e for e in result.events if e.kind == "not_identifiable"]
    assert [(e.data["parameter"], e.data["axes"]) for e in said] == [("gravity_force_B", ["x"])]
    assert np.isnan(result.params["gravity_force_B"][0]) and np.isfinite(result.params["gravity_force_B"][1:]).all()
    # what hapticlab run's summary says of it
    assert weight_identified(result.params) == "not along B's x (turn the tool about another axis)"
    assert weight_identified({**result.params, "gravity_force_B": [0.0, 0.0, -3.4]}) == "every axis"
    assert weight_identified({"gravity_force_B": [0.0, 0.0, -3.4]}) == ""  # (rls: not reported)
    rec = read_recording(tmp_path / "axial.mcap")
    commands = [m for _, m in rec.topics["/haptic/command"]]
    assert not any(m["enabled"] for m in commands) and not any(m["force_D"] != [0.0, 0.0, 0.0] for m in commands)
    after = [
        m["reason"] for t, m in rec.topics["/haptic/command"] if t > said[0].t_ns and m["reason"] != "session ended"
    ]
    assert after and all(
        r in (f"estimator not converged ({said[0].message})", f"parameters not yet identified ({said[0].message})")
        for r in after
    )
    assert after[-1] == f"parameters not yet identified ({said[0].message})"
    assert any(e.kind == "converged" for e in result.events)  # the flag at the pose: not what turns the force on
    assert "turn the tool about another axis" in after[0]
    assert not [e for e in result.events if e.kind == "fault"]
