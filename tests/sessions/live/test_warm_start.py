"""Sessions save the estimator's final state and a later session warm-starts from it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, calibration_path, run_session
from hapticlab.sessions.recording import read_recording


def kalman_demo(duration, **options):
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", f"session.duration={duration}"])
    config["estimator"] = {"name": "kalman", **options}
    return config


@pytest.fixture(scope="module")
def first_session(tmp_path_factory):
    path = tmp_path_factory.mktemp("warm") / "first.mcap"
    result = run_session(build_session(kalman_demo(10.0)), out=path)
    return result, read_recording(path)


def test_session_end_saves_the_estimator_state(first_session):
    result, rec = first_session
    saved = calibration_path(result.path)
    assert saved == result.path.with_name("first.calibration.json") and saved.exists()
    state = json.loads(saved.read_text())
    assert state["estimator"] == "kalman" and state["converged_force"]
    meta = rec.metadata["hapticlab.estimator_state"]
    assert json.loads(meta["force"]) == state["force"] and meta["estimator"] == "kalman"
    assert rec.metadata["hapticlab.summary"]["estimator_state_path"] == str(saved)


def test_next_session_warm_starts(first_session, tmp_path):
    result, _ = first_session
    warm = run_session(
        build_session(kalman_demo(3.0, warm_start=str(calibration_path(result.path)))), out=tmp_path / "second.mcap"
    )
    print(
        f"\nsession warm start: force stage converged at sample {warm.first_converged_force}, "
        f"torque at {warm.first_converged_torque} (cold: {result.first_converged_force}, "
        f"{result.first_converged_torque})"
    )
    assert warm.first_converged_force < 10 and warm.first_converged_torque < 10
    assert np.allclose(warm.params["gravity_force_B"], result.params["gravity_force_B"], atol=0.05)
    assert not [e for e in warm.events if e.kind == "payload_change"]


def test_estimator_events_are_recorded(tmp_path):
    # the demo's tool with 100 g hung on it from 5 s: the session records the payload change
    config = kalman_demo(9.0)
    config["world"]["contacts"] = [{"kind": "hanging_mass", "start": 5.0, "duration": 1e9, "mass": 0.1}]
    result = run_session(build_session(config), out=tmp_path / "payload.mcap")
    kinds = [e.kind for e in result.events]
    assert kinds.count("payload_change") == 1, result.events
    rec = read_recording(tmp_path / "payload.mcap")
    recorded = [m for _, m in rec.topics["/events"] if m["kind"] == "payload_change"]
    assert len(recorded) == 1 and "payload change" in recorded[0]["message"]


def test_bad_warm_start_is_a_config_error(tmp_path):
    bad = tmp_path / "bad.calibration.json"
    bad.write_text(json.dumps({"estimator": "rls"}))
    with pytest.raises(Exception, match="warm_start"):
        build_session(kalman_demo(1.0, warm_start=str(bad)))
