"""A real ``hapticlab run`` killed with SIGKILL: the recording keeps all but its last second.

Two kills: the session's process alone (its recording's writer process sees the
pipe close and finishes the file: complete, up to the tick in progress), and
the session with its writer at once (a power cut: the file ends at the last
flush, about once a second, and ``hapticlab recover`` salvages it).
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time

import pytest

from hapticlab.sessions.recording import RecordingError, read_recording, recover


def start_run(path) -> subprocess.Popen:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys; from hapticlab.sessions.cli import main; sys.exit(main())",
            "run",
            "demo",
            "--duration",
            "60",
            "--out",
            str(path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )  # a group of its own
    deadline = time.monotonic() + 60
    while not (path.exists() and path.stat().st_size > 0) and time.monotonic() < deadline:
        time.sleep(0.05)  # the writer writes the header once the session has started
    assert path.exists(), proc.stderr.read() if proc.poll() is not None else "no recording started"
    return proc


def kill_after(proc: subprocess.Popen, seconds: float, group: bool) -> int:
    time.sleep(seconds)
    assert proc.poll() is None
    t_kill = time.monotonic_ns()
    os.killpg(proc.pid, signal.SIGKILL) if group else proc.kill()
    proc.wait(10)
    proc.stdout.close()
    proc.stderr.close()
    return t_kill


def test_a_killed_session_s_writer_finishes_its_recording(tmp_path):
    path = tmp_path / "killed.mcap"
    t_kill = kill_after(start_run(path), 4.0, group=False)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # the writer finishes the file once it sees the pipe close
        try:
            rec = read_recording(path)
            break
        except RecordingError:
            time.sleep(0.1)
    else:
        pytest.fail("the writer did not finish the killed session's file")
    last = max(t for messages in rec.topics.values() for t, _ in messages)
    lost_ms = (t_kill - last) * 1e-6
    print(f"session killed alone: last message {lost_ms:.1f} ms before the kill")
    assert 0 <= lost_ms < 100  # the tick in progress (and a slow one) at most
    seq = rec.field("/sensor/wrench", "seq")
    assert seq.tolist() == list(range(len(seq))) and len(seq) > 2500  # gap-free, ~4 s at 1 kHz


def test_a_session_killed_with_its_writer_loses_at_most_its_last_second(tmp_path):
    path = tmp_path / "power-cut.mcap"
    t_kill = kill_after(start_run(path), 4.0, group=True)
    with pytest.raises(RecordingError, match="hapticlab recover"):
        read_recording(path)
    fixed = tmp_path / "fixed.mcap"
    stats = recover(path, fixed)
    rec = read_recording(fixed)
    last = max(t for messages in rec.topics.values() for t, _ in messages)
    lost_ms = (t_kill - last) * 1e-6
    print(f"session and writer killed: {stats['messages']} messages salvaged, last {lost_ms:.0f} ms before the kill")
    assert 0 <= lost_ms <= 1500  # the flush interval (1 s) and the chunk in progress
    seq = rec.field("/sensor/wrench", "seq")
    assert seq.tolist() == list(range(len(seq))) and len(seq) > 1500
