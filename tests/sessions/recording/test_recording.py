"""Tests for hapticlab.sessions.recording: MCAP writing, reading and recovery."""

from __future__ import annotations

import datetime as dt
import json
import math
import os
import shutil
import struct
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from processes import PROCESS_STOP_S

import hapticlab
from hapticlab.core.errors import UserError
from hapticlab.sessions import recording
from hapticlab.sessions.recording import Recorder, RecordingError, iter_messages, read_recording, recover

HERE = Path(__file__).resolve().parent
NAN = float("nan")


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def _is_type(value, name: str) -> bool:
    return {
        "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
        "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "boolean": lambda v: isinstance(v, bool),
        "string": lambda v: isinstance(v, str),
        "array": lambda v: isinstance(v, list),
        "object": lambda v: isinstance(v, dict),
        "null": lambda v: v is None,
    }[name](value)


def validate(instance, schema: dict, where: str = "$") -> None:
    """A small JSON-schema check (type, required, properties, items, min/maxItems)."""
    types = schema.get("type")
    if types is not None:
        types = types if isinstance(types, list) else [types]
        assert any(_is_type(instance, t) for t in types), f"{where}: {instance!r} is not {types}"
    if isinstance(instance, dict):
        for key in schema.get("required", []):
            assert key in instance, f"{where}: required {key!r} missing"
        props = schema.get("properties", {})
        extra = schema.get("additionalProperties")
        for key, value in instance.items():
            if key in props:
                validate(value, props[key], f"{where}.{key}")
            elif isinstance(extra, dict):
                validate(value, extra, f"{where}.{key}")
    if isinstance(instance, list):
        assert len(instance) >= schema.get("minItems", 0), f"{where}: too few items"
        assert len(instance) <= schema.get("maxItems", 10**9), f"{where}: too many items"
        if isinstance(schema.get("items"), dict):
            for i, value in enumerate(instance):
                validate(value, schema["items"], f"{where}[{i}]")


def _jsonable(obj):
    """What a message should read back as: numpy -> lists, non-finite floats -> None."""
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def _estimate(i: int) -> dict:
    return {
        "contact_force_S": np.array([0.1 * i, 0.0, -0.2]),
        "contact_torque_S": [0.0, 0.01 * i, 0.0],
        "contact": i % 3 == 0,
        "converged_force": i > 2,
        "converged_torque": i > 4,
        "params": {"gravity_force_B": np.array([0.0, 0.0, -1.5 - i]), "cog_S": [0.0, 0.0, 0.05]},
        "cov_diag": np.full(6, 1e-3 / (i + 1)),
    }


def _every_topic_messages() -> list[tuple[str, int, dict]]:
    """A short session: several messages on every topic, numpy and plain inputs, a NaN, nulls."""
    msgs: list[tuple[str, int, dict]] = []
    for i in range(10):
        t = 1_000_000_000 + i * 1_000_000
        msgs.append(
            (
                "/sensor/wrench",
                t,
                {
                    "force_S": np.array([1.5 + i, -2.25, NAN if i == 3 else 9.81]),
                    "torque_S": [0.01, 0.02 * i, -0.03],
                    "seq": np.int64(100 + i),
                    "status": 0 if i != 5 else 1,
                },
            )
        )
        msgs.append(
            (
                "/kinematics/pose",
                t + 10,
                {
                    "quat_BE": np.array([1.0, 0.0, 0.0, 0.0]),
                    "p_BoEo_B": None if i == 0 else [0.4, 0.1 * i, 0.3],
                    "joints": None if i == 0 else np.linspace(0, 1, 6) * i,
                },
            )
        )
        msgs.append(
            (
                "/aligned/sample",
                t + 20,
                {
                    "force_S": [1.5 + i, -2.25, 9.81],
                    "torque_S": [0.0, 0.0, 0.0],
                    "quat_BE": [0.5, 0.5, 0.5, 0.5],
                    "seq": 100 + i,
                    "status": 0,
                    "stale": i == 7,
                },
            )
        )
        msgs.append(("/estimator/rls", t + 30, _estimate(i)))
        msgs.append(("/estimator/paper", t + 31, _estimate(2 * i)))
        cmd = {"force_D": [0.0, 0.1 * i, 0.0], "enabled": i != 4}
        if i == 4:
            cmd["reason"] = "estimator not converged"
        msgs.append(("/haptic/command", t + 40, cmd))
        msgs.append(
            (
                "/haptic/state",
                t + 50,
                {
                    "pose": {"quat_DH": [1.0, 0.0, 0.0, 0.0], "p_DoHo_D": np.array([0.01 * i, 0.0, 0.1])},
                    "buttons": i % 4,
                },
            )
        )
    return msgs


METADATA = {
    "hapticlab.session": {
        "config": {"sensor": {"plugin": "netft", "rate_hz": 7000}, "estimators": ["rls", "paper"]},
        "plugins": {"netft": "1.2.0", "rls": "builtin"},
    },
    "hapticlab.calibration": {"counts_per_force": 1_000_000, "counts_per_torque": 1_000_000, "units": "N, N·m"},
}
SUMMARY = {"final_params": {"gravity_force_B": [0.0, 0.0, -11.5]}, "note": "ok"}


@pytest.fixture
def every_topic(tmp_path):
    path = tmp_path / "session.mcap"
    msgs = _every_topic_messages()
    with Recorder(path, METADATA) as rec:
        for topic, t, m in msgs:
            rec.write(topic, t, m)
        rec.event(
            1_005_000_000, "haptic_disabled", "estimator not converged", estimator="rls", residual_N=[0.5, 0.0, 0.1]
        )
        rec.event(1_009_000_000, "converged", "rls converged")
        assert rec.messages_written == len(msgs) + 2
        rec.close(SUMMARY)
    return path, msgs


def _chunks(path: Path) -> list[tuple[int, int, list[tuple[str, int, bytes]]]]:
    """(start offset, end offset, [(topic, time, data)]) of every chunk, in file order, via mcap (the time: the log
    time minus the session's clock offset, as the reader gives it)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        session = next(m.metadata for m in reader.iter_metadata() if m.name == "hapticlab.session")
        offset = int(session["clock_offset_ns"])
        topics = {c.id: c.topic for c in summary.channels.values()}
        out = []
        for index in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(index.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            msgs = [
                (topics[r.channel_id], r.log_time - offset, r.data)
                for r in breakup_chunk(chunk)
                if isinstance(r, Message)
            ]
            out.append((index.chunk_start_offset, index.chunk_start_offset + index.chunk_length, msgs))
    return out


def _by_topic(msgs) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list] = {}
    for topic, t, data in msgs:
        out.setdefault(topic, []).append((t, json.loads(data)))
    return out


# --------------------------------------------------------------------------
# writing and reading back
# --------------------------------------------------------------------------


def test_every_topic_round_trips(every_topic):
    path, msgs = every_topic
    rec = read_recording(path)
    expected_topics = {t for t, _, _ in msgs} | {"/events"}
    assert set(rec.topic_names) == expected_topics
    assert len(expected_topics) == 8  # 6 fixed topics + 2 estimators
    for topic in expected_topics - {"/events"}:
        want = [(t, _jsonable(m)) for tp, t, m in msgs if tp == topic]
        assert rec.topics[topic] == want, topic
    events = [m for _, m in rec.messages("/events")]
    assert events[0] == {
        "kind": "haptic_disabled",
        "message": "estimator not converged",
        "data": {"estimator": "rls", "residual_N": [0.5, 0.0, 0.1]},
    }
    assert events[1] == {"kind": "converged", "message": "rls converged"}  # no empty "data"

    # helpers: times, stacked fields, NaN for null, dtypes
    t = rec.t_ns("/sensor/wrench")
    assert t.dtype == np.int64 and t[0] == 1_000_000_000 and np.all(np.diff(t) == 1_000_000)
    force = rec.field("/sensor/wrench", "force_S")
    assert force.shape == (10, 3) and force.dtype == float
    assert np.isnan(force[3, 2]) and np.isnan(force).sum() == 1
    assert rec.field("/sensor/wrench", "seq").tolist() == list(range(100, 110))
    p = rec.field("/kinematics/pose", "p_BoEo_B")
    assert p.shape == (10, 3) and np.all(np.isnan(p[0])) and np.allclose(p[1], [0.4, 0.1, 0.3])
    assert rec.field("/aligned/sample", "stale").dtype == bool
    g = rec.field("/estimator/rls", "params.gravity_force_B")
    assert np.allclose(g[:, 2], -1.5 - np.arange(10))
    assert rec.field("/haptic/state", "pose.p_DoHo_D").shape == (10, 3)
    reasons = rec.field("/haptic/command", "reason")
    assert reasons[4] == "estimator not converged" and reasons[0] is None
    with pytest.raises(KeyError, match="no_such_field"):
        rec.field("/sensor/wrench", "no_such_field")
    with pytest.raises(KeyError, match="/nope"):
        rec.t_ns("/nope")
    assert rec.start_ns == 1_000_000_000
    assert rec.duration == pytest.approx((1_009_000_050 - 1_000_000_000) * 1e-9)


def test_channels_schemas_and_compression(every_topic):
    path, _ = every_topic
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary.chunk_indexes, "messages must be in chunks"
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert summary.statistics.message_count == 72
        schema_ids = {}
        for channel in summary.channels.values():
            assert channel.message_encoding == "json"
            schema = summary.schemas[channel.schema_id]
            assert schema.encoding == "jsonschema"
            schema_ids[channel.topic] = channel.schema_id
            doc = json.loads(schema.data)
            assert doc["$schema"] == "https://json-schema.org/draft/2020-12/schema"
            assert doc["title"] == schema.name and doc["type"] == "object"
            assert doc["required"] and set(doc["required"]) <= set(doc["properties"])
            for name, prop in doc["properties"].items():
                assert prop.get("description"), f"{channel.topic}.{name} has no description"
        assert schema_ids["/estimator/rls"] == schema_ids["/estimator/paper"]  # one shared schema
        assert len(set(schema_ids.values())) == 7
        # every recorded message is valid against its channel's schema
        n = 0
        for schema, channel, message in reader.iter_messages():
            validate(json.loads(message.data), json.loads(schema.data), channel.topic)
            assert message.log_time == message.publish_time
            n += 1
        assert n == 72
    # units and frames are stated in the descriptions
    desc = recording.TOPICS["/sensor/wrench"]["properties"]["force_S"]["description"]
    assert "N" in desc and "frame S" in desc


def test_metadata_records(every_topic):
    path, _ = every_topic
    rec = read_recording(path)
    assert {"hapticlab.session", "hapticlab.calibration", "hapticlab.summary"} <= set(rec.metadata)
    for values in rec.metadata.values():
        assert all(isinstance(k, str) and isinstance(v, str) for k, v in values.items())
    session = rec.metadata["hapticlab.session"]
    assert json.loads(session["config"]) == METADATA["hapticlab.session"]["config"]
    assert json.loads(session["plugins"]) == METADATA["hapticlab.session"]["plugins"]
    assert session["hapticlab_version"] == hapticlab.__version__
    start = dt.datetime.fromisoformat(session["start_time"])
    assert abs((dt.datetime.now(dt.UTC) - start).total_seconds()) < 600
    assert int(session["start_monotonic_ns"]) > 0
    assert rec.meta("hapticlab.calibration", "counts_per_force") == 1_000_000
    assert rec.metadata["hapticlab.calibration"]["units"] == "N, N·m"  # strings stay strings
    assert rec.meta("hapticlab.summary", "final_params") == SUMMARY["final_params"]
    assert rec.meta("hapticlab.summary", "messages_written") == 72


def test_iter_messages_streams_in_time_order(every_topic):
    path, msgs = every_topic
    got = list(iter_messages(path, topics=["/haptic/command", "/sensor/wrench"]))
    assert {tp for tp, _, _ in got} == {"/haptic/command", "/sensor/wrench"}
    assert len(got) == 20
    times = [t for _, t, _ in got]
    assert times == sorted(times)
    assert got[0] == ("/sensor/wrench", 1_000_000_000, _jsonable(msgs[0][2]))


def test_out_of_order_writes_read_back_in_time_order(tmp_path):
    path = tmp_path / "r.mcap"
    times = [50, 10, 30, 20, 40, 30]
    with Recorder(path, chunk_size=64) as rec:  # tiny chunks: the disorder spans chunks
        for i, t in enumerate(times):
            rec.write("/haptic/command", t, {"force_D": [0.0, 0.0, float(i)], "enabled": True})
            rec.event(t + 1, "k", str(i))
    rec = read_recording(path)
    assert rec.t_ns("/haptic/command").tolist() == sorted(times)
    assert rec.field("/haptic/command", "force_D")[:, 2].tolist() == [1.0, 3.0, 2.0, 5.0, 4.0, 0.0]
    streamed = [t for _, t, _ in iter_messages(path)]
    assert streamed == sorted(streamed) and len(streamed) == 12


def test_unknown_topic_refused(tmp_path):
    path = tmp_path / "r.mcap"
    with Recorder(path) as rec:
        with pytest.raises(ValueError, match="'/bogus'"):
            rec.write("/bogus", 1, {"x": 1})
        with pytest.raises(ValueError, match="/estimator/"):
            rec.write("/estimator/", 1, {})
        with pytest.raises(ValueError, match="/estimator/a b"):
            rec.write("/estimator/a b", 1, {})
        with pytest.raises(ValueError, match="t_ns"):
            rec.write("/events", -5, {"kind": "x", "message": "y"})
        with pytest.raises(TypeError):
            rec.write("/events", 1.5, {"kind": "x", "message": "y"})
        with pytest.raises(TypeError, match="/events"):
            rec.write("/events", 2, {"kind": "x", "message": object()})
        rec.write("/events", 3, {"kind": "ok", "message": "still fine"})
        assert rec.messages_written == 1
    rec = read_recording(path)
    assert rec.topic_names == ["/events"]
    assert rec.topics["/events"] == [(3, {"kind": "ok", "message": "still fine"})]


def test_close_twice_is_harmless_and_write_after_close_is_refused(tmp_path):
    path = tmp_path / "r.mcap"
    rec = Recorder(path)
    rec.write("/haptic/command", 5, {"force_D": [0, 0, 0], "enabled": True})
    rec.close({"n": 1})
    rec.close()
    rec.close({"n": 2})
    assert rec.closed
    with pytest.raises(RuntimeError, match="closed"):
        rec.write("/haptic/command", 6, {"force_D": [0, 0, 0], "enabled": True})
    r = read_recording(path)
    assert len(r) == 1 and r.metadata["hapticlab.summary"]["n"] == "1"


def test_existing_file_is_not_overwritten(tmp_path):
    path = tmp_path / "r.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="overwrite"):
        Recorder(path)
    assert path.read_bytes() == b"precious"
    Recorder(path, overwrite=True).close()
    assert read_recording(path).topics == {}


def test_not_an_mcap_file(tmp_path):
    path = tmp_path / "notes.mcap"
    path.write_text("t,fx,fy,fz\n0,1,2,3\n")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        read_recording(path)
    with pytest.raises(RecordingError, match="not an MCAP file"):
        iter_messages(path)
    with pytest.raises(RecordingError, match="not an MCAP file"):
        recover(path, tmp_path / "fixed.mcap")


def test_flush_is_time_based(tmp_path, monkeypatch):
    """Messages reach the file once flush_interval_s has passed on the monotonic clock, not before."""
    clock = [100.0]
    monkeypatch.setattr(recording.sinks, "_monotonic", lambda: clock[0])
    path = tmp_path / "live.mcap"
    rec = Recorder(path, flush_interval_s=1.0)

    def on_disk() -> int:
        copy = tmp_path / "copy.mcap"
        shutil.copyfile(path, copy)
        return recover(copy, tmp_path / "copy_fixed.mcap", force=True)["messages"]

    for i in range(10):
        rec.write("/haptic/command", i, {"force_D": [0.0, 0.0, float(i)], "enabled": True})
    assert on_disk() == 0  # still in the chunk in progress
    clock[0] += 0.9
    rec.write("/haptic/command", 10, {"force_D": [0.0, 0.0, 10.0], "enabled": True})
    assert on_disk() == 0
    clock[0] += 0.2
    rec.write("/haptic/command", 11, {"force_D": [0.0, 0.0, 11.0], "enabled": True})
    assert on_disk() == 12
    rec.write("/haptic/command", 12, {"force_D": [0.0, 0.0, 12.0], "enabled": True})
    assert on_disk() == 12
    rec.close()
    assert len(read_recording(path)) == 13


# --------------------------------------------------------------------------
# crashes and recovery
# --------------------------------------------------------------------------


KILL_AT = 3000
"""The tick at which the crashing writer kills itself (~3 s at 1 kHz)."""


def _crashing_writer(spawn_process, tmp_path: Path, path: Path, *options: str) -> tuple[int, int, int | None]:
    """Run the helper recording at ~1 kHz (64 MiB chunks: only the 1 s time-based flush reaches the disk) until
    it SIGKILLs itself at tick KILL_AT (``group`` in options: with its writer process); (the stamp of the tick
    before the kill, of the kill's tick, the writer process's pid or None)."""
    env = dict(os.environ)
    package_parent = str(Path(hapticlab.__file__).parent.parent)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_parent, env.get("PYTHONPATH")) if p)
    ticks = tmp_path / "ticks.txt"
    proc = spawn_process(
        [sys.executable, str(HERE / "_crashing_writer.py"), str(path), "1.0", str(64 << 20), str(KILL_AT), str(ticks)]
        + list(options),
        "the crashing writer",
        env=env,
        start_new_session=True,  # a group of its own
    )
    line = proc.first_line().split()
    assert line[:1] == ["ready"], (line, proc.stderr.read() if proc.poll() is not None else "")
    assert proc.wait_for_exit(PROCESS_STOP_S + KILL_AT * 1e-3) == -9  # SIGKILL: no atexit, no finally, no close
    previous_ns, kill_ns = (int(x) for x in ticks.read_text().split())
    return previous_ns, kill_ns, int(line[1]) if len(line) > 1 else None


@pytest.mark.parametrize("layout", ["samples", "json-blocks", "blocks", "blocks+process"])
def test_sigkilled_writer_is_recovered_up_to_the_last_flush(tmp_path, layout, spawn_process):
    """Killed with no chance to close (with writer="process": the session and its writer process both)."""
    sys.path.insert(0, str(HERE))
    try:
        from _crashing_writer import wrench
    finally:
        sys.path.remove(str(HERE))
    path = tmp_path / "crash.mcap"
    options = [] if layout == "samples" else layout.split("+")
    previous_ns, _, writer_pid = _crashing_writer(spawn_process, tmp_path, path, *options, "group")
    assert (writer_pid is not None) == ("process" in options)

    with pytest.raises(RecordingError, match="hapticlab recover") as info:
        read_recording(path)
    assert "\n" not in str(info.value)

    fixed = tmp_path / "fixed.mcap"
    stats = recover(path, fixed)
    rec = read_recording(fixed)
    per_message = {t: len(rec.blocks[t]) if t in rec.blocks else len(m) for t, m in rec.topics.items()}
    assert stats["messages"] == sum(per_message.values()) and stats["complete"] is False
    assert stats["corrupt_chunks"] == 0 and stats["orphan_messages"] == 0
    assert stats["topics"] == per_message
    block_topics = {"/sensor/wrench", "/aligned/sample", "/estimator/late"}
    assert set(rec.blocks) == (block_topics if layout != "samples" else set())
    assert (
        rec.format_version == {"samples": 3, "json-blocks": 2, "blocks": 3, "blocks+process": 3}[layout]
    )  # the writer's default
    assert stats["lost_tail_bytes"] >= 0

    # nothing older than 1.5 s before the kill's tick is lost (flush interval 1 s)
    last = max(t for msgs in rec.topics.values() for t, _ in msgs)
    assert previous_ns - 1_500_000_000 <= last <= previous_ns
    # every salvaged message is intact, and they are a gap-free prefix of what was written
    wrenches = rec.topics["/sensor/wrench"]
    assert len(wrenches) > 1000  # at least ~1.5 s at 1 kHz
    assert [m["seq"] for _, m in wrenches] == list(range(len(wrenches)))
    assert all(m == wrench(m["seq"]) for _, m in wrenches)
    assert np.all(np.diff(rec.t_ns("/sensor/wrench")) > 0)
    aligned_seq = rec.field("/aligned/sample", "seq")
    if layout != "samples":  # whole blocks of 7, every sample
        assert len(wrenches) % 7 == 0 and aligned_seq.tolist() == list(range(len(aligned_seq)))
        seq_at = {t: m["seq"] for t, m in wrenches}
        t_last = int(rec.t_ns("/estimator/late")[-1])  # params ride on the last sample of each block
        assert rec.estimates("late").params == {"seq": [float(seq_at[t_last])]}
    else:
        assert aligned_seq.tolist() == list(range(0, 2 * len(aligned_seq), 2))
    assert rec.field("/estimator/late", "params.seq").size > 0  # a channel registered mid-file survives
    assert next(rec.messages("/events"))[1]["kind"] == "tick"
    # metadata survives, and the recovery is documented in the file
    assert rec.meta("hapticlab.session", "config") == {"preset": "crash-test"}
    assert rec.meta("hapticlab.calibration", "counts_per_force") == 1e6
    assert rec.meta("hapticlab.recovered", "messages") == stats["messages"]
    with open(fixed, "rb") as f:
        assert {c.compression for c in make_reader(f).get_summary().chunk_indexes} == {"zstd"}


def test_writer_process_finishes_the_file_of_a_killed_session(tmp_path, spawn_process):
    """SIGKILL of the recording process alone: its writer process sees the pipe close and finishes the file.

    Everything handed over (every tick but the one in progress) is in a complete,
    indexed file that reads without ``recover``; no summary (the session never closed it).
    """
    sys.path.insert(0, str(HERE))
    try:
        from _crashing_writer import wrench
    finally:
        sys.path.remove(str(HERE))
    path = tmp_path / "killed.mcap"
    previous_ns, _, writer_pid = _crashing_writer(spawn_process, tmp_path, path, "blocks", "process")
    deadline = time.monotonic() + PROCESS_STOP_S  # against hanging, not a timing assertion
    while _alive(writer_pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(writer_pid), "the writer process outlived its session"

    rec = read_recording(path)  # complete: no recover needed
    assert rec.meta("hapticlab.session", "config") == {"preset": "crash-test"}
    assert "hapticlab.summary" not in rec.metadata  # the session never closed it
    seqs = rec.field("/sensor/wrench", "seq")
    assert seqs.tolist() == list(range(len(seqs)))  # gap-free: whole blocks, in order
    assert len(seqs) == 7 * KILL_AT  # every tick before the kill's: each was handed over as it ended
    assert int(rec.t_ns("/sensor/wrench")[-1]) == previous_ns  # the last sample of the tick before the kill
    assert rec.field("/sensor/wrench", "force_S")[-1].tolist() == wrench(int(seqs[-1]))["force_S"]


def _alive(pid: int) -> bool:
    """Whether ``pid`` still runs (a zombie awaiting its reaper counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.fixture
def many_chunks(tmp_path):
    """A closed recording with many small chunks (every topic from the first chunk on)."""
    path = tmp_path / "chunks.mcap"
    with Recorder(path, METADATA, chunk_size=4096) as rec:
        for i in range(600):
            t = 5_000_000_000 + i * 1_000_000
            rec.write(
                "/sensor/wrench", t, {"force_S": [i, 2 * i, 3.5], "torque_S": [0.0, 0.1, -i], "seq": i, "status": 0}
            )
            rec.write("/estimator/rls", t + 1, _estimate(i))
            rec.write("/haptic/command", t + 2, {"force_D": [0.0, 0.0, 0.001 * i], "enabled": True})
    chunks = _chunks(path)
    assert len(chunks) > 20
    return path, chunks


def test_truncated_at_arbitrary_offsets_recovers_complete_chunks(tmp_path, many_chunks):
    path, chunks = many_chunks
    data = path.read_bytes()
    first_start = chunks[0][0]
    # the Footer record (opcode, length, summary_start, ...) precedes the closing magic;
    # the DataEnd record ends where the summary starts
    summary_start = struct.unpack_from("<BQQ", data, len(data) - 8 - 29)[2]
    rng = np.random.default_rng(7)
    cuts = sorted(
        {
            first_start - 3,  # inside the metadata before the first chunk
            first_start + 50,  # inside the first chunk
            chunks[0][1],  # exactly at the end of the first chunk
            chunks[4][1] - 1,  # one byte short of a complete chunk
            chunks[4][1] + 5,  # inside the message index after a chunk
            chunks[-1][1],  # all chunks complete
            summary_start - 1,  # DataEnd incomplete
            summary_start,  # DataEnd complete, summary missing
            *rng.integers(first_start, len(data), 10).tolist(),
        }
    )
    broken = tmp_path / "broken.mcap"
    fixed = tmp_path / "fixed.mcap"
    for cut in cuts:
        broken.write_bytes(data[:cut])
        with pytest.raises(RecordingError, match="hapticlab recover"):
            read_recording(broken)
        stats = recover(broken, fixed, force=True)
        complete = [c for c in chunks if c[1] <= cut]
        expected = [m for c in complete for m in c[2]]
        assert stats["messages"] == len(expected), cut
        assert stats["chunks"] >= len(complete) and stats["corrupt_chunks"] == 0
        rec = read_recording(fixed)
        assert rec.topics == _by_topic(expected), cut
        if cut >= summary_start:  # only (part of) the summary section is missing
            assert stats["complete"] and stats["lost_tail_bytes"] == 0
        else:
            assert not stats["complete"]
            assert 0 <= stats["lost_tail_bytes"] < cut
        if cut >= first_start:
            assert rec.meta("hapticlab.session", "config") == METADATA["hapticlab.session"]["config"]
            assert rec.meta("hapticlab.calibration", "counts_per_force") == 1_000_000
        else:
            assert "hapticlab.calibration" not in rec.metadata
    # cut inside the magic: nothing to salvage
    broken.write_bytes(data[:5])
    with pytest.raises(RecordingError, match="nothing to recover"):
        recover(broken, fixed, force=True)


def test_recover_of_a_complete_file_keeps_everything(tmp_path, every_topic):
    path, msgs = every_topic
    fixed = tmp_path / "copy.mcap"
    stats = recover(path, fixed)
    assert stats["complete"] and stats["lost_tail_bytes"] == 0 and stats["messages"] == len(msgs) + 2
    a, b = read_recording(path), read_recording(fixed)
    assert a.topics == b.topics and a.schemas == b.schemas
    assert {k: v for k, v in b.metadata.items() if k != "hapticlab.recovered"} == a.metadata
    with pytest.raises(UserError, match="different file"):
        recover(path, path)


def test_damaged_chunk_is_skipped_not_salvaged_as_garbage(tmp_path, many_chunks):
    path, chunks = many_chunks
    data = bytearray(path.read_bytes())
    start, end, lost = chunks[3]
    data[(start + end) // 2] ^= 0xFF
    broken = tmp_path / "damaged.mcap"
    broken.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match="hapticlab recover"):
        read_recording(broken)  # CRCs are checked on read
    fixed = tmp_path / "fixed.mcap"
    stats = recover(broken, fixed)
    assert stats["corrupt_chunks"] == 1 and stats["complete"]
    expected = [m for i, c in enumerate(chunks) if i != 3 for m in c[2]]
    assert stats["messages"] == len(expected) == sum(len(c[2]) for c in chunks) - len(lost)
    assert read_recording(fixed).topics == _by_topic(expected)


def test_the_message_encoder_writes_the_values_json_would_and_null_for_what_is_not_finite():
    """The recorder's JSON encoder (orjson) gives the values the standard library writes (its own spelling of
    a float may differ, e.g. 1e-05), numpy included, null for NaN and ±inf, and TypeError for an object."""
    from hapticlab.sessions.recording.metadata import json_default
    from hapticlab.sessions.recording.writer import _encode

    def reference(value):
        return json.dumps(value, separators=(",", ":"), allow_nan=False, default=json_default)

    rng = np.random.default_rng(3)
    messages = [
        {"force_D": rng.normal(size=3).tolist(), "enabled": True, "reason": "", "source_t_ns": 2**64 - 1},
        {"pose": {"quat_DH": rng.normal(size=4), "p_DoHo_D": [0.0, -0.0, 1e-300]}, "buttons": 3, "v_DHo_D": None},
        {
            "kind": "fault",
            "message": 'ünïcode "quoted"\n\ttab \u2603',
            "data": {"a": np.float64(0.1), "b": np.int64(-7), "c": (1, 2), "d": rng.normal(size=(2, 3))[:, 1]},
        },
        [1e308, -1e-308, 1e-05, 0.1 + 0.2, False, "x", {3: "int key"}],
    ]
    for message in messages:
        assert json.loads(_encode(message)) == json.loads(reference(message))
    assert json.loads(_encode({"x": float("nan"), "y": [float("inf"), 1.0], "z": np.array([np.nan, -np.inf])})) == {
        "x": None,
        "y": [None, 1.0],
        "z": [None, None],
    }
    assert json.loads(_encode([np.float32(0.1)])) == [0.1]  # a float32 written as the float32 it is
    with pytest.raises(TypeError):
        _encode({"x": object()})


@pytest.mark.skipif(not hasattr(os, "SCHED_BATCH"), reason="Linux scheduling policies")
def test_the_writer_process_never_preempts_the_loop_that_wakes_it(tmp_path):
    """The writer process runs as SCHED_BATCH: a hand-over wakes it without taking the loop's core."""
    recorder = Recorder(tmp_path / "batch.mcap", writer="process")
    try:
        assert os.sched_getscheduler(recorder.writer_pid) == os.SCHED_BATCH
        assert os.sched_getscheduler(0) != os.SCHED_BATCH  # the loop's own process keeps its policy
    finally:
        recorder.close()
