"""Log times are Unix time (the session clock plus the ``clock_offset_ns`` read once at the start), so Foxglove shows
real dates; every reader gives the times of a file from before the offset, and reads such a file as before."""

from __future__ import annotations

import time

import numpy as np
import pytest
from helpers import as_before_the_offset
from mcap.reader import make_reader
from mcap.writer import Writer

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import Recorder, RecordingError, iter_blocks, open_recording, read_recording
from hapticlab.sessions.recording.columnar import iter_chunks
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.mcapfile import file_stats

DAY_NS = 86_400 * 10**9


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A 2 s simulated demo session, the wall clock read just before and after it, and its copy as written
    before the offset (log times on the session clock, no ``clock_offset_ns``)."""
    folder = tmp_path_factory.mktemp("wall_clock")
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", "session.duration=2"])
    session = build_session(config)
    before = time.time_ns()
    run_session(session, out=folder / "new.mcap")
    after = time.time_ns()
    return folder / "new.mcap", as_before_the_offset(folder / "new.mcap", folder / "old.mcap"), before, after


def raw(path):
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time) for _, c, m in make_reader(f).iter_messages()]


def test_every_recorded_message_is_stamped_within_a_day_of_the_wall_clock(demo):
    path, _, before, after = demo
    messages = raw(path)
    assert len({topic for topic, _, _ in messages}) >= 9 and len(messages) > 500
    now = time.time_ns()
    assert all(abs(log - now) < DAY_NS and publish == log for _, log, publish in messages)
    rec = open_recording(path)
    offset = int(rec.metadata["hapticlab.session"]["clock_offset_ns"])
    assert abs(offset - (time.time_ns() - time.monotonic_ns())) < 10**9  # Unix time minus the monotonic clock
    # the session starts between the two readings of the wall clock (a simulated session's later ticks run ahead
    # of it); its /events log time is the session_start event's time plus the offset
    ((_, start_log, _),) = [m for m in messages if m[0] == "/events"][:1]
    assert before <= start_log <= after
    assert rec.events[0].kind == "session_start" and rec.events[0].t_ns == start_log - offset


def test_every_reader_gives_the_times_of_the_file_written_before_the_offset(demo):
    new, old, _, _ = demo
    assert max(log for _, log, _ in raw(old)) < 10**17  # the copy's log times are the session clock's (old files)
    a, b = open_recording(new), open_recording(old)
    assert "clock_offset_ns" not in b.metadata["hapticlab.session"] and a.topic_names == b.topic_names
    for topic in a.topic_names:
        np.testing.assert_array_equal(a.t_ns(topic), b.t_ns(topic), err_msg=topic)
        assert list(a.messages(topic)) == list(b.messages(topic)), topic
    assert a.events == b.events and (a.start_ns, a.end_ns) == (b.start_ns, b.end_ns)
    started = int(a.metadata["hapticlab.session"]["start_monotonic_ns"])  # the session clock when the file opened
    assert started <= a.start_ns < started + 60 * 10**9
    assert read_recording(new).topics == read_recording(old).topics
    assert file_stats(new) == file_stats(old)
    for (t1, ts1, m1, k1), (t2, ts2, m2, k2) in zip(iter_blocks(new), iter_blocks(old), strict=True):
        assert (t1, ts1, k1) == (t2, ts2, k2)
        if k1:
            np.testing.assert_array_equal(m1["t_ns"], m2["t_ns"])
        else:
            assert m1 == m2
    topics = ["/aligned/sample", "/haptic/command", "/events"]
    for x, y in zip(iter_chunks(new, topics), iter_chunks(old, topics)):
        np.testing.assert_array_equal(x["/aligned/sample"]["t_ns"], y["/aligned/sample"]["t_ns"])
        assert [t for t, _ in x["/haptic/command"]] == [t for t, _ in y["/haptic/command"]]
    np.testing.assert_array_equal(load_stream(new).samples.t_ns, load_stream(old).samples.t_ns)


def test_a_recorder_given_an_offset_keeps_it_and_a_bad_one_is_refused(tmp_path):
    path = tmp_path / "given.mcap"
    with Recorder(path, {"hapticlab.session": {"clock_offset_ns": 1_700_000_000 * 10**9}}) as rec:
        rec.event(5, "note", "five ns into the session")
    assert raw(path) == [("/events", 1_700_000_000 * 10**9 + 5, 1_700_000_000 * 10**9 + 5)]
    assert read_recording(path).events[0].t_ns == 5
    for bad in ("soon", -1, 2**62):
        with pytest.raises(ValueError, match="clock_offset_ns"):
            Recorder(tmp_path / "bad.mcap", {"hapticlab.session": {"clock_offset_ns": bad}})
        assert not (tmp_path / "bad.mcap").exists()


def test_a_file_whose_offset_is_not_a_number_is_one_line_naming_it(tmp_path):
    path = tmp_path / "odd.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("hapticlab.session", {"clock_offset_ns": "yesterday"})
        channel = writer.register_channel("/events", "json", 0)
        writer.add_message(channel, log_time=7, publish_time=7, data=b'{"kind": "k", "message": "m"}')
        writer.finish()
    with pytest.raises(RecordingError, match=r"hapticlab.session, clock_offset_ns: must be an integer") as caught:
        read_recording(path)
    assert "\n" not in str(caught.value)
