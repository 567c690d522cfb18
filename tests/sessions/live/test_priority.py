"""A paced session's loop thread runs at SCHED_FIFO while it ticks (session.realtime_priority), and only then."""

from __future__ import annotations

import os

import pytest

from hapticlab.core.host.registry import ConfigError
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, priority, run_session
from hapticlab.sessions.recording import read_recording

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux scheduling policies")


def demo(*overrides: str, realtime: bool = True):
    config, _ = load_config("demo")
    return apply_overrides(config, [f"session.realtime={str(realtime).lower()}", "session.duration=0.3", *overrides])


def _policies_while_ticking(session) -> list[tuple[int, int]]:
    """(policy, priority) of the thread that sends each haptic command (the loop's), one per tick."""
    seen = []
    send = session.haptic.send
    session.haptic.send = lambda command: (
        seen.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)) or send(command)
    )
    return seen


def _fifo_permitted() -> bool:
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except PermissionError:
        return False
    os.sched_setscheduler(0, *before)
    return True


def test_a_paced_session_ticks_at_sched_fifo_and_gives_the_thread_its_policy_back(tmp_path, paced_run):
    if not _fifo_permitted():
        pytest.skip("this user may not ask for SCHED_FIFO (no CAP_SYS_NICE, no rtprio limit)")
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    session = build_session(demo("session.realtime_priority=42"))
    seen = _policies_while_ticking(session)
    result = paced_run(session, tmp_path / "fifo.mcap")
    *ticks, final = seen  # the final zero command goes out once the loop has stopped ticking
    assert set(ticks) == {(os.SCHED_FIFO, 42)} and final == before
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
    rec = read_recording(result.path)
    # every tick of the 0.3 s at 1 kHz ran at that policy, or was skipped by an overrun (counted in its events)
    skipped = sum(e.data["ticks_skipped"] for e in result.events if e.kind == "overrun")
    assert len(ticks) == len(rec.topics["/haptic/command"]) - 1 and 295 <= len(ticks) + skipped <= 301
    assert rec.metadata["hapticlab.summary"]["realtime_priority"] == "42"
    assert not [e for e in result.events if e.kind == "realtime_priority_unavailable"]


def test_a_refused_priority_is_said_and_the_session_runs_at_the_ordinary_one(tmp_path, monkeypatch, paced_run):
    def refuse(pid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(priority.os, "sched_setscheduler", refuse)
    before = os.sched_getscheduler(0)
    session = build_session(demo())
    seen = _policies_while_ticking(session)
    result = paced_run(session, tmp_path / "refused.mcap")
    assert seen and {policy for policy, _ in seen} == {before}
    [event] = [e for e in result.events if e.kind == "realtime_priority_unavailable"]
    assert "SCHED_FIFO priority 50 refused (Operation not permitted)" in event.message
    assert "session.realtime_priority = 0" in event.message
    assert result.samples >= 290  # the session ran
    rec = read_recording(result.path)
    assert rec.metadata["hapticlab.summary"]["realtime_priority"] == "0"
    assert any(e.kind == "realtime_priority_unavailable" for e in rec.events)


@pytest.mark.parametrize("overrides", [("session.realtime_priority=0",), ()], ids=["priority 0", "not paced"])
def test_no_priority_is_asked_for_at_0_or_in_a_simulated_session(tmp_path, overrides, paced_run):
    before = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    session = build_session(demo(*overrides, realtime=bool(overrides)))
    seen = _policies_while_ticking(session)
    result = (paced_run if session.settings.realtime else run_session)(session, out=tmp_path / "plain.mcap")
    assert seen and set(seen) == {before}
    assert read_recording(result.path).metadata["hapticlab.summary"]["realtime_priority"] == "0"


@pytest.mark.parametrize(
    ("value", "why"), [("100", "got 100$"), ("-1", "got -1$"), ('"high"', "got 'high'$"), ("50.0", "got 50.0$")]
)
def test_a_priority_out_of_range_is_refused_naming_the_key(value, why):
    with pytest.raises(
        ConfigError,
        match=rf"^session.realtime_priority: must be a whole number >= 0 and <= 99 "
        rf"\(SCHED_FIFO; 0: the ordinary policy\), {why}",
    ):
        build_session(demo(f"session.realtime_priority={value}"))
