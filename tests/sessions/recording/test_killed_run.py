"""A paced session killed with SIGKILL: the recording keeps all but its last second.

Two kills: the session's process alone (its recording's writer process sees the
pipe close and finishes the file: complete, up to the last hand-over of the
taps), and the session with its writer at once (a power cut: the file ends at
the last flush, about once a second, and ``hapticlab recover`` salvages it).

The session kills itself, at a known sensor read, as SIGKILL from outside would
(no ``finally``, no close), and first writes down the session clock of that
tick and of the one before: what was lost is measured on the session's own
clock, never on the test's.
"""

from __future__ import annotations

import sys
import time

import pytest
from processes import PROCESS_STOP_S

from hapticlab.sessions.live.taps import HAND_OVER_NS
from hapticlab.sessions.recording import RecordingError, read_recording, recover

KILL_AT_READ = 4000
"""The sensor read (tick) at which the session kills itself: ~4 s into a paced 1 kHz session."""
SAMPLE_NS = 1_000_000
"""The demo's sensor period (1 kHz), ns."""
FLUSH_NS = 1_500_000_000
"""What a power cut may lose at most, ns: the writer's flush interval (1 s) and the chunk in progress."""

KILLED_SESSION = """
import os, signal, sys
from pathlib import Path
from hapticlab.core import hookimpl
from hapticlab.core.host.registry import Registry, make_plugin_manager
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session

out, kill_at, group, ticks = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "group", Path(sys.argv[4])

class KillingSensor(SimSensor):
    reads, previous_ns = 0, 0

    def read_block(self, until_ns):
        self.reads += 1
        if self.reads == kill_at:
            ticks.write_text(f"{self.previous_ns} {until_ns}")  # the tick before, and this one (session clock)
            os.killpg(0, signal.SIGKILL) if group else os.kill(os.getpid(), signal.SIGKILL)
        self.previous_ns = until_ns
        return super().read_block(until_ns)

class Plugin:
    @hookimpl
    def register_sensors(self, register):
        register("killing", KillingSensor)

pm = make_plugin_manager(load_entry_points=False)
pm.register(Plugin(), name="tests")
config = apply_overrides(load_config("demo")[0], ["session.duration=60", "sensor.name=killing"])
run_session(build_session(config, Registry(pm)), out=out)
"""


def killed_session(spawn_process, tmp_path, path, group: bool) -> tuple[int, int]:
    """Run the demo paced (a group of its own) until it kills itself; (the tick before the kill, the kill's) ns."""
    ticks = tmp_path / "ticks.txt"
    proc = spawn_process(
        [sys.executable, "-c", KILLED_SESSION, str(path), str(KILL_AT_READ), "group" if group else "alone", str(ticks)],
        "the paced demo session",
        start_new_session=True,
    )
    assert proc.wait_for_exit(PROCESS_STOP_S + KILL_AT_READ * 1e-3) == -9, proc.stderr.read()
    previous_ns, kill_ns = (int(x) for x in ticks.read_text().split())
    return previous_ns, kill_ns


def test_a_killed_session_s_writer_finishes_its_recording(tmp_path, spawn_process):
    path = tmp_path / "killed.mcap"
    previous_ns, kill_ns = killed_session(spawn_process, tmp_path, path, group=False)
    deadline = time.monotonic() + PROCESS_STOP_S  # against hanging, not a timing assertion
    while time.monotonic() < deadline:  # the writer finishes the file once it sees the pipe close
        try:
            rec = read_recording(path)
            break
        except RecordingError:
            time.sleep(0.1)
    else:
        pytest.fail("the writer did not finish the killed session's file")
    last = max(t for messages in rec.topics.values() for t, _ in messages)
    print(f"session killed alone: last message {(kill_ns - last) * 1e-6:.1f} ms before the kill's tick")
    # every tick handed over is there: all but the ticks since the last hand-over (every 20 ms of session clock)
    assert previous_ns - HAND_OVER_NS - SAMPLE_NS <= last <= previous_ns
    seq = rec.field("/sensor/wrench", "seq")
    assert seq.tolist() == list(range(len(seq)))  # gap-free
    assert rec.t_ns("/sensor/wrench")[-1] >= previous_ns - HAND_OVER_NS - SAMPLE_NS
    assert len(seq) >= KILL_AT_READ - 1 - (HAND_OVER_NS + SAMPLE_NS) // SAMPLE_NS  # sample i is stamped i ms in


def test_a_session_killed_with_its_writer_loses_at_most_its_last_second(tmp_path, spawn_process):
    path = tmp_path / "power-cut.mcap"
    previous_ns, kill_ns = killed_session(spawn_process, tmp_path, path, group=True)
    with pytest.raises(RecordingError, match="hapticlab recover"):
        read_recording(path)
    fixed = tmp_path / "fixed.mcap"
    stats = recover(path, fixed)
    rec = read_recording(fixed)
    last = max(t for messages in rec.topics.values() for t, _ in messages)
    lost_ms = (kill_ns - last) * 1e-6
    print(f"session and writer killed: {stats['messages']} messages salvaged, last {lost_ms:.0f} ms before the kill")
    assert previous_ns - FLUSH_NS <= last <= previous_ns  # the flush interval (1 s) and the chunk in progress
    seq = rec.field("/sensor/wrench", "seq")
    assert seq.tolist() == list(range(len(seq)))
    assert rec.t_ns("/sensor/wrench")[-1] >= previous_ns - FLUSH_NS
    assert len(seq) >= KILL_AT_READ - 1 - FLUSH_NS // SAMPLE_NS
