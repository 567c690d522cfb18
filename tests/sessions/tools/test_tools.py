"""The tool library: records kept between sessions, a known tool starting warm, and its command."""

from __future__ import annotations

import os

import pytest

from hapticlab.core.errors import ConfigError, UserError
from hapticlab.sessions.cli import main
from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.tools import ToolLibrary, ToolRecord, tool_settings

RECORD = ToolRecord("needle", 0.35, (0.002, -0.001, 0.04), (1.0, -0.8, 2.5), (0.03, -0.02, 0.01), "kalman", "t", 3)


def test_a_record_and_its_state_round_trip_and_are_forgotten_together(tmp_path):
    library = ToolLibrary(tmp_path / "tools")
    assert library.names() == [] and library.get("needle") is None
    library.save(RECORD, {"x": [1.0, 2.0]})
    assert library.names() == ["needle"] and library.get("needle") == RECORD
    assert library.state("needle") == tmp_path / "tools" / "needle.state.json"
    library.save(RECORD, None)  # (a state that no longer fits is not left behind)
    assert library.state("needle") is None and library.get("needle") == RECORD
    assert library.forget("needle") == [tmp_path / "tools" / "needle.toml"] and library.names() == []
    assert library.forget("needle") == []


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"mass_kg = 0.3\ncog_S = [0, 0\n", "invalid TOML"),
        (b"mass_kg = 0.3\n", "KeyError"),
        (b"mass_kg = -1\ncog_S = [0, 0, 0.04]\n", "mass_kg must be a positive number"),
        (b"mass_kg = 0.3\ncog_S = [0, 0]\n", "expected three numbers"),
        (b"mass_kg = 0.3\xff\n", "not UTF-8 text (byte 13)"),
        (b"# " + b"x" * (70 << 10) + b"\n", "larger than 64 KiB"),
        (b"mass_kg = 0.3\ncog_S = [0, 0, 0.04]\nsessions = inf\n", "OverflowError"),
        (b"mass_kg = 0.3\ncog_S = [0, nan, 0.04]\n", "non-finite vector"),
    ],
)
def test_a_record_that_is_not_one_is_named_in_one_line(tmp_path, content, says):
    (tmp_path / "bad.toml").write_bytes(content)
    with pytest.raises(UserError, match=r"bad\.toml") as exc:
        ToolLibrary(tmp_path).get("bad")
    assert says in str(exc.value) and "\n" not in str(exc.value)


def test_a_name_is_a_file_name_not_a_path():
    for bad in ("../etc/passwd", ".hidden", "a/b", "", "x" * 65):
        with pytest.raises(ConfigError):
            ToolLibrary("/nonexistent").record_path(bad)
    with pytest.raises(ConfigError, match=r"^tool\.name: must be a tool name"):
        tool_settings({"tool": {"name": "../x"}})
    with pytest.raises(ConfigError, match=r"^tool\.mass: unknown option"):
        tool_settings({"tool": {"mass": 0.3}})


def demo(tmp_path, seconds: float, out: str, **settings):
    config, _ = load_config("demo")
    base = {"session.realtime": False, "session.duration": seconds, "tool.name": "needle"}
    config = apply_settings(config, {**base, "tool.library": str(tmp_path / "tools"), **settings})
    session = build_session(config)
    result = run_session(session, out=tmp_path / out)
    t0 = result.events[0].t_ns
    return session, [((e.t_ns - t0) * 1e-9, e.kind, e.message) for e in result.events]


def test_a_session_saves_its_tool_and_the_next_starts_warm_with_the_force_on_in_its_first_second(tmp_path):
    """The demo's simulated tool weighs 0.35 kg. Unknown, it is identified from the motion (the force comes on
    after seconds) and saved; known, the next session loads kalman's state: the force on at once. The identified
    mass is not stated (it is no weighed one, and a stated mass turns the pull watch off)."""
    _, events = demo(tmp_path, 8.0, "first.mcap")
    said = {kind: message for _, kind, message in events}
    assert "is not in the library" in said["tool"] and "saved to" in said["tool_saved"]
    first_on = next(t for t, kind, _ in events if kind == "haptic_enabled")
    record = ToolLibrary(tmp_path / "tools").get("needle")
    assert record is not None and record.sessions == 1 and abs(record.mass_kg - 0.35) < 0.01
    assert record.recording == str(tmp_path / "first.mcap") and record.estimator == "kalman"
    session, events = demo(tmp_path, 3.0, "second.mcap")
    said = {kind: message for _, kind, message in events}
    assert f"from the library ({record.mass_kg:.3f} kg, 1 sessions" in said["tool"]
    assert "starts from its state" in said["tool"]
    on = next(t for t, kind, _ in events if kind == "haptic_enabled")
    assert on < 0.01 < 1.0 < first_on
    resolved = session.resolved_config
    assert resolved["haptic"]["tool_mass"] == 0.0
    assert resolved["estimator"]["warm_start"] == str(tmp_path / "tools" / "needle.state.json")
    assert resolved["tool"]["known"] and ToolLibrary(tmp_path / "tools").get("needle").sessions == 2


def test_a_session_that_did_not_identify_its_tool_leaves_the_library_alone(tmp_path):
    _, events = demo(tmp_path, 0.5, "short.mcap")
    said = {kind: message for _, kind, message in events}
    assert (
        "not saved to its library: the force was held at the end (parameters not yet identified"
        in said["tool_not_saved"]
    )
    assert not (tmp_path / "tools").exists()


def test_a_session_that_ended_latched_leaves_the_library_alone(tmp_path):
    """Started resting on tissue, lifted slowly at 5 s: the weight identified is the support's lighter one, and the
    force latched (a pull straight down). Saved, the next session would start from 0.14 kg for a 0.35 kg tool."""
    rest = {"kind": "indentation", "start": -1.1, "duration": 6.2, "peak_force": 2.0, "ramp": 0.1}
    config, _ = load_config("demo")
    config = apply_settings(config, {"session.realtime": False, "session.duration": 7.0, "tool.name": "needle"})
    config = apply_settings(config, {"tool.library": str(tmp_path / "tools")})
    config["world"]["contacts"] = [rest]
    result = run_session(build_session(config), out=tmp_path / "rested.mcap")
    said = {e.kind: e.message for e in result.events}
    assert "haptic_latched" in said and "(pull straight down: re-arm needed)" in said["tool_not_saved"]
    assert ToolLibrary(tmp_path / "tools").names() == []


def test_a_stated_mass_and_warm_start_are_the_users_not_the_librarys(tmp_path):
    ToolLibrary(tmp_path / "tools").save(RECORD, {"x": [0.0]})
    config, _ = load_config("demo")
    settings = {"tool.name": "needle", "tool.library": str(tmp_path / "tools"), "haptic.tool_mass": 0.4}
    session = build_session(apply_settings(config, {**settings, "estimator.name": "rls"}))
    assert session.resolved_config["haptic"]["tool_mass"] == 0.4  # given: kept
    assert "warm_start" not in session.resolved_config["estimator"]  # rls takes none
    assert session.tool.message().endswith("the estimator starts cold")
    unnamed = build_session(apply_settings(config, {"tool.library": str(tmp_path / "tools")}))
    assert unnamed.tool.library == str(tmp_path / "tools")  # (a told change saves there)


def test_the_tool_command_lists_shows_and_forgets(tmp_path, capsys):
    folder = str(tmp_path / "tools")
    assert main(["tool", "--library", folder, "list"]) == 0
    assert "no tools in" in capsys.readouterr().out
    ToolLibrary(folder).save(RECORD, {"x": [0.0]})
    assert main(["tool", "--library", folder, "list"]) == 0
    out = capsys.readouterr().out
    assert "needle" in out and "0.350" in out and "warm start" in out
    assert main(["tool", "--library", folder, "show", "needle"]) == 0
    assert "mass_kg = 0.35" in capsys.readouterr().out
    assert main(["tool", "--library", folder, "forget", "needle"]) == 0
    assert capsys.readouterr().out.count("removed ") == 2 and not os.listdir(folder)
    for action in ("show", "forget"):
        assert main(["tool", "--library", folder, action, "needle"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "needle: no such tool" in err
