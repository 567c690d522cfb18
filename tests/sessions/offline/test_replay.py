"""Shadow estimators in a session, and ``hapticlab replay``."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import as_before_the_offset
from mcap.reader import make_reader

from hapticlab.core.host.registry import ConfigError
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.offline.replay import replay
from hapticlab.sessions.recording import read_recording


@pytest.fixture(scope="module")
def with_shadows(tmp_path_factory):
    config, _ = load_config("demo")
    # kinematics at the sensor's rate: every sample has a pose at its own stamp, so the live loop never
    # extrapolates and a replay sees the very inputs the session did (at 500 Hz the replay interpolates where
    # the loop extrapolated, ~1e-3 N apart, enough to move the paper's ‖Δx‖ < ε test by a second on one CPU)
    config = apply_overrides(
        config,
        [
            "session.realtime=false",
            "session.duration=4.0",
            "kinematics.rate_hz=1000.0",
            "shadows.batch={}",
            'shadows.rls_tight={name="rls", force_threshold=0.5}',
        ],
    )
    path = tmp_path_factory.mktemp("shadow") / "s.mcap"
    result = run_session(build_session(config), out=path)
    return result, read_recording(path)


def test_shadows_run_side_by_side_and_are_recorded(with_shadows):
    result, rec = with_shadows
    for topic in ("/estimator/rls", "/estimator/batch", "/estimator/rls_tight"):
        assert len(rec.topics[topic]) == result.samples
    # the shadow with a tighter threshold is the same algorithm: it converges at the same sample
    conv = {t: int(np.argmax(rec.field(t, "converged_force"))) for t in ("/estimator/rls", "/estimator/rls_tight")}
    assert conv["/estimator/rls"] == conv["/estimator/rls_tight"]
    config = rec.meta("hapticlab.session", "config")
    assert config["shadows"]["rls_tight"]["force_threshold"] == 0.5 and config["shadows"]["batch"]["name"] == "batch"


def test_shadow_config_errors_name_the_key():
    config, _ = load_config("demo")
    with pytest.raises(ConfigError, match=r"^shadows.kalman: the primary estimator already records"):
        build_session(apply_overrides(config, ["shadows.kalman={}"]))
    with pytest.raises(ConfigError, match=r"^shadows.fast.force_treshold: unknown option"):
        build_session(apply_overrides(config, ['shadows.fast={name="rls", force_treshold=1}']))
    with pytest.raises(ConfigError, match=r"^shadows.k.name: unknown estimator 'nope'"):
        build_session(apply_overrides(config, ['shadows.k={name="nope"}']))


def test_replay_adds_the_new_estimator_and_compares(with_shadows, tmp_path):
    result, rec = with_shadows
    out = replay(result.path, "rls", tmp_path / "replayed.mcap")
    new = read_recording(tmp_path / "replayed.mcap")
    assert out["topic"] == "/estimator/rls_replay"
    assert set(new.topics) == set(rec.topics) | {"/estimator/rls_replay"}
    for topic, messages in rec.topics.items():
        assert len(new.topics[topic]) == len(messages)
    # the same estimator, offline, on the same inputs: the same estimates
    for field in ("contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque"):
        assert np.array_equal(rec.field("/estimator/rls", field), new.field("/estimator/rls_replay", field)), field
    cmp = out["comparison"]
    assert cmp["/estimator/rls_replay"]["converged_force_at"] == cmp["/estimator/rls"]["converged_force_at"]
    assert cmp["/estimator/rls_replay"]["contact_agreement_pct"] > 99.9
    assert new.metadata["hapticlab.replay"]["estimator"] == "rls"


def test_replay_command(with_shadows, tmp_path, capsys):
    result, _ = with_shadows
    assert main(["replay", str(result.path), "--estimator", "batch", "-o", str(tmp_path / "b.mcap")]) == 0
    text = capsys.readouterr().out
    assert "/estimator/batch_replay (new)" in text and "contact agreement" in text
    assert main(["replay", str(result.path), "--estimator", "batch", "-o", str(result.path)]) == 2
    assert "would overwrite the recording" in capsys.readouterr().err


def log_times(path) -> dict[str, list[int]]:
    """Each topic's log times as the file holds them (Unix time since the offset), sorted."""
    out: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(message.log_time)
    return {topic: sorted(times) for topic, times in out.items()}


def test_a_replay_keeps_the_original_s_log_times_and_dates_an_older_file_from_its_start(with_shadows, tmp_path):
    result, rec = with_shadows
    offset = int(rec.metadata["hapticlab.session"]["clock_offset_ns"])
    replay(result.path, "rls", tmp_path / "new.mcap")
    replayed = read_recording(tmp_path / "new.mcap")
    assert int(replayed.metadata["hapticlab.session"]["clock_offset_ns"]) == offset
    original, copied = log_times(result.path), log_times(tmp_path / "new.mcap")
    for topic, times in original.items():  # every sample at its original date (a block's: its last sample's)
        assert set(times) <= set(copied[topic]), topic
        np.testing.assert_array_equal(replayed.t_ns(topic), rec.t_ns(topic), err_msg=topic)
    assert copied["/events"] == original["/events"] and copied["/haptic/command"] == original["/haptic/command"]
    t_ns = rec.t_ns("/sensor/wrench")  # the new estimator's samples at the wrench's times, on the same clock
    np.testing.assert_array_equal(replayed.t_ns("/estimator/rls_replay"), t_ns)
    assert copied["/estimator/rls_replay"] == (t_ns + offset).tolist()
    # a file from before the offset (log times on the session clock): the replay dates it from its start_time
    # (ms, read a moment after start_monotonic_ns), and reads back the same times
    old = as_before_the_offset(result.path, tmp_path / "old.mcap")
    replay(old, "rls", tmp_path / "old-replayed.mcap")
    again = read_recording(tmp_path / "old-replayed.mcap")
    assert abs(int(again.metadata["hapticlab.session"]["clock_offset_ns"]) - offset) < 10**9
    assert again.topics == replayed.topics
