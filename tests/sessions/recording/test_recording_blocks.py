"""The recording's layouts: format 3 writes the sensor-rate topics in CDR blocks, format 2 in
JSON blocks, format 1 one message per sample; the reader gives every consumer the same samples and arrays
from all three."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory  # tests only: the reference CDR decoder for ros2msg schemas

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import (
    Recorder,
    RecordingError,
    iter_messages,
    open_recording,
    read_recording,
    recover,
)
from hapticlab.sessions.recording.cdr_layouts import CDR_BLOCK_SCHEMAS
from hapticlab.sessions.recording.reader import Recording
from hapticlab.sessions.recording.schemas import (
    BLOCK_SCHEMA_TITLES,
    BLOCK_TOPICS,
    ESTIMATOR_BLOCK_SCHEMA,
    FORMAT_VERSION,
    SCHEMAS,
)

NAN = float("nan")
BLOCK_TOPIC_NAMES = ("/sensor/wrench", "/aligned/sample", "/estimator/rls")


class OldTaps:
    """The taps as they were before format 2 (one ``Recorder.write`` per sample), verbatim."""

    def __init__(self, recorder: Recorder):
        self.rec = recorder

    def wrenches(self, wrenches) -> None:
        write = self.rec.write
        for w in wrenches:
            write(
                "/sensor/wrench",
                w.t_ns,
                {
                    "force_S": w.force_S.tolist(),
                    "torque_S": w.torque_S.tolist(),
                    "seq": int(w.seq),
                    "status": int(w.status),
                },
            )

    def aligned(self, block) -> None:
        write = self.rec.write
        quat_BE, seq, status, stale = (
            block.quat_BE.tolist(),
            block.seq.tolist(),
            block.status.tolist(),
            block.stale.tolist(),
        )
        force, torque = block.force_S.tolist(), block.torque_S.tolist()
        for i, t in enumerate(block.t_ns.tolist()):
            write(
                "/aligned/sample",
                t,
                {
                    "force_S": force[i],
                    "torque_S": torque[i],
                    "quat_BE": quat_BE[i],
                    "seq": seq[i],
                    "status": status[i],
                    "stale": stale[i],
                },
            )

    def estimates(self, topic: str, est, params=None, cov_diag=None) -> None:
        write = self.rec.write
        n = len(est.t_ns)
        f, tau = est.contact_force_S.tolist(), est.contact_torque_S.tolist()
        contact, cf, ct = est.contact.tolist(), est.converged_force.tolist(), est.converged_torque.tolist()
        for i, t in enumerate(est.t_ns.tolist()):
            last = i == n - 1
            write(
                topic,
                t,
                {
                    "contact_force_S": f[i],
                    "contact_torque_S": tau[i],
                    "contact": contact[i],
                    "converged_force": cf[i],
                    "converged_torque": ct[i],
                    "params": params if last else None,
                    "cov_diag": cov_diag if last else None,
                },
            )


def _arrays(block: dict, dtypes: dict) -> SimpleNamespace:
    return SimpleNamespace(
        **{k: np.array(block[k], dtype=dtypes.get(k, float)) for k in block if k not in ("params", "cov_diag")}
    )


def _write_old_layout(new: Recording, path: Path) -> None:
    """The session in ``new`` written again the old way: the same blocks through the old taps, the rest as is."""
    ints = {"t_ns": np.int64, "seq": np.int64, "status": np.int64}
    with Recorder(path, {"hapticlab.session": {"format_version": 1}}) as rec:
        old = OldTaps(rec)
        per_tick = [
            (t, topic, m) for topic in new.topic_names if topic not in BLOCK_TOPIC_NAMES for t, m in new.topics[topic]
        ]
        for t, topic, m in per_tick:
            rec.write(topic, t, m)
        for b in new.blocks["/sensor/wrench"]:
            a = _arrays(b, ints)
            old.wrenches(
                [
                    SimpleNamespace(
                        t_ns=int(a.t_ns[i]),
                        force_S=a.force_S[i],
                        torque_S=a.torque_S[i],
                        seq=a.seq[i],
                        status=a.status[i],
                    )
                    for i in range(len(a.t_ns))
                ]
            )
        for b in new.blocks["/aligned/sample"]:
            old.aligned(_arrays(b, {**ints, "stale": bool}))
        for b in new.blocks["/estimator/rls"]:
            flags = dict.fromkeys(("contact", "converged_force", "converged_torque"), bool)
            old.estimates("/estimator/rls", _arrays(b, {**ints, **flags}), b.get("params"), b.get("cov_diag"))


def _write_json_blocks(new: Recording, path: Path) -> None:
    """The session in ``new`` written again in format 2: the same blocks as JSON, the rest as is."""
    with Recorder(path, block_encoding="json") as rec:
        for topic in new.topic_names:
            if topic in BLOCK_TOPIC_NAMES:
                for b in new.blocks[topic]:
                    rec.write_block(topic, {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in b.items()})
            else:
                for t, m in new.topics[topic]:
                    rec.write(topic, t, m)


@pytest.fixture(scope="module")
def both_layouts(tmp_path_factory):
    """A real simulated session at 7 kHz (format 3), the same data in format 1 and in format 2."""
    tmp = tmp_path_factory.mktemp("layouts")
    config, _ = load_config("demo")
    config = apply_overrides(config, ["session.realtime=false", "sensor.rate_hz=7000.0", "estimator.name=rls"])
    result = run_session(build_session(config), out=tmp / "new.mcap", duration=0.4)
    new = read_recording(result.path)
    _write_old_layout(new, tmp / "old.mcap")
    _write_json_blocks(new, tmp / "json.mcap")
    return result, tmp / "new.mcap", tmp / "old.mcap", tmp / "json.mcap"


def _same_array(a: np.ndarray, b: np.ndarray) -> bool:
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")


def test_a_live_session_writes_blocks(both_layouts):
    result, new_path, old_path, json_path = both_layouts
    new, old = read_recording(new_path), read_recording(old_path)
    assert new.format_version == FORMAT_VERSION == 3 and old.format_version == 1
    assert read_recording(json_path).format_version == 2
    assert Recording(new_path, {}, {}).format_version == 1  # files from before format_version
    assert len(new.topics["/sensor/wrench"]) == result.samples
    with open(new_path, "rb") as f:
        summary = make_reader(f).get_summary()
    counts = summary.statistics.channel_message_counts
    by_topic = {c.topic: (summary.schemas[c.schema_id].name, counts[c.id]) for c in summary.channels.values()}
    encodings = {
        c.topic: (summary.schemas[c.schema_id].encoding, c.message_encoding) for c in summary.channels.values()
    }
    for topic in BLOCK_TOPIC_NAMES:
        title, n_messages = by_topic[topic]
        assert title in CDR_BLOCK_SCHEMAS and encodings[topic] == ("ros2msg", "cdr")
        assert n_messages * 5 < len(new.topics[topic])  # ~7 samples per message at 7 kHz and 1 kHz ticks
    assert by_topic["/haptic/command"] == ("hapticlab.HapticCommand", len(new.topics["/haptic/command"]))
    assert encodings["/haptic/command"] == ("jsonschema", "json")
    assert set(new.blocks) == set(BLOCK_TOPIC_NAMES) and not old.blocks


@pytest.mark.parametrize("other", ["format 1", "format 2"])
def test_the_layouts_read_the_same(both_layouts, other):
    _, new_path, old_path, json_path = both_layouts
    old_path = old_path if other == "format 1" else json_path
    for opener in (read_recording, open_recording):
        new, old = opener(new_path), opener(old_path)
        assert new.topic_names == old.topic_names
        for topic in new.topic_names:
            assert _same_array(new.t_ns(topic), old.t_ns(topic)), topic
        for topic in BLOCK_TOPIC_NAMES:
            names = set(old.topics[topic][0][1]) - {"params", "cov_diag"}
            for name in names:
                assert _same_array(new.field(topic, name), old.field(topic, name)), (topic, name)
            assert list(new.messages(topic)) == list(old.messages(topic)), topic
        for a, b in zip(new.wrench(), old.wrench()):
            assert _same_array(a, b)
        for a, b in zip(new.poses(), old.poses()):
            assert _same_array(a, b)
        e_new, e_old = new.estimates("rls"), old.estimates("rls")
        for name in ("t_ns", "contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque"):
            assert _same_array(getattr(e_new, name), getattr(e_old, name)), name
        assert e_new.params is not None and e_new.params == e_old.params
        g_new = new.field("/estimator/rls", "params.gravity_force_B")
        assert _same_array(g_new, old.field("/estimator/rls", "params.gravity_force_B"))
        assert np.isfinite(g_new).any()  # the reports, NaN between them
    for topic in BLOCK_TOPIC_NAMES:
        assert list(iter_messages(new_path, topic)) == list(iter_messages(old_path, topic))
    assert read_recording(new_path).topics == read_recording(old_path).topics


def test_params_ride_on_the_last_sample_of_their_block(both_layouts):
    _, new_path, _, _ = both_layouts
    rec = read_recording(new_path)
    blocks = rec.blocks["/estimator/rls"]
    reported = [b for b in blocks if "params" in b]
    assert 0 < len(reported) < len(blocks) and all("cov_diag" in b for b in reported)
    assert rec.estimates("rls").params == reported[-1]["params"]
    samples = iter(rec.topics["/estimator/rls"])
    for b in blocks:
        mine = [next(samples)[1] for _ in b["t_ns"]]
        assert [m["params"] for m in mine] == [None] * (len(mine) - 1) + [b.get("params")]
        assert [m["cov_diag"] for m in mine] == [None] * (len(mine) - 1) + [b.get("cov_diag")]


def test_cdr_blocks_are_valid_for_their_ros2msg_schemas(both_layouts):
    """What Foxglove decodes: mcap-ros2-support's reference decoder parses each schema (ros2msg) and reads
    every CDR block message to the last byte, with the values our reader gives."""
    _, new_path, _, _ = both_layouts
    rec = read_recording(new_path)
    offset = int(rec.metadata["hapticlab.session"]["clock_offset_ns"])
    factory = DecoderFactory()
    seen = set()
    with open(new_path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=list(BLOCK_TOPIC_NAMES)):
            decode = factory.decoder_for(channel.message_encoding, schema)
            assert decode is not None, channel.topic
            ros = decode(message.data)
            layout = CDR_BLOCK_SCHEMAS[schema.name]
            n = len(ros.t_ns)
            assert message.log_time == ros.t_ns[-1] + offset  # Unix time: the session clock + the offset
            ours = next(b for b in rec.blocks[channel.topic] if b["t_ns"][-1] == ros.t_ns[-1])
            for column in layout.columns:
                assert np.array_equal(
                    np.asarray(getattr(ros, column.ros_name)).reshape(ours[column.name].shape),
                    ours[column.name],
                    equal_nan=True,
                ), (channel.topic, column.name)
                assert len(getattr(ros, column.ros_name)) == n * column.width
            if layout.report:
                assert (json.loads(ros.params) if ros.params else None) == ours.get("params")
                assert ros.has_cov_diag == ("cov_diag" in ours)
                if ros.has_cov_diag:
                    assert list(ros.cov_diag) == ours["cov_diag"]
                    seen.add("params")
            seen.add(channel.topic)
    assert seen == {*BLOCK_TOPIC_NAMES, "params"}


def test_a_cdr_block_byte_by_byte(tmp_path):
    """A small estimator block against hand-worked CDR: offsets counted from after the 4-byte header."""
    path = tmp_path / "one.mcap"
    with Recorder(path) as rec:
        rec.write_block(
            "/estimator/x",
            {
                "t_ns": [7],
                "contact_force_S": [[1.0, 2.0, 3.0]],
                "contact": [True],
                "params": {"a": [0.5]},
                "cov_diag": [2.0],
            },
        )
    with open(path, "rb") as f:
        ((schema, channel, message),) = make_reader(f).iter_messages()
    assert (schema.encoding, channel.message_encoding, schema.name) == (
        "ros2msg",
        "cdr",
        "hapticlab/msg/EstimatorEstimateBlock",
    )
    u32, i64, f64 = (
        (lambda v: v.to_bytes(4, "little")),
        (lambda v: v.to_bytes(8, "little")),
        (lambda v: np.float64(v).tobytes()),
    )
    text = b'{"a":[0.5]}\x00'  # 12 bytes with the NUL
    expected = (
        b"\x00\x01\x00\x00"  # header; offsets below from here
        + u32(1)
        + bytes(4)
        + i64(7)  # 0 t_ns: count, pad to 8, one int64 at 8
        + u32(3)
        + bytes(4)
        + f64(1.0)
        + f64(2.0)
        + f64(3.0)  # 16 contact_force_S: count, pad, at 24
        + u32(0)  # 48 contact_torque_S: empty (no padding after the count)
        + u32(1)
        + b"\x01"  # 52 contact: count, one bool at 56
        + bytes(3)
        + u32(0)  # 57 pad to 60, converged_force: empty
        + u32(0)  # 64 converged_torque: empty
        + u32(len(text))
        + text  # 68 params: byte count with the NUL, at 72..83
        + u32(1)
        + f64(2.0)  # 84 cov_diag: count at 84, float64 at 88 (aligned to 8)
        + b"\x01"
    )  # 96 has_cov_diag
    assert message.data == expected
    ros = DecoderFactory().decoder_for("cdr", schema)(message.data)
    assert (ros.t_ns, ros.contact, ros.params, ros.has_cov_diag) == ([7], [True], '{"a":[0.5]}', True)
    rec = read_recording(path)
    assert rec.topics["/estimator/x"] == [
        (7, {"contact_force_S": [1.0, 2.0, 3.0], "contact": True, "params": {"a": [0.5]}, "cov_diag": [2.0]})
    ]


def test_json_block_messages_match_their_schemas(both_layouts):
    """Format 2: every block message has its schema's required fields, arrays one per sample."""
    _, _, _, json_path = both_layouts
    rec = read_recording(json_path)
    for topic in BLOCK_TOPIC_NAMES:
        schema = rec.schemas[topic]
        assert schema == SCHEMAS[schema["title"]]
        assert schema is not None and schema["title"].endswith("Block") and schema["title"] in BLOCK_SCHEMA_TITLES
        for b in rec.blocks[topic]:
            assert set(schema["required"]) <= set(b) <= set(schema["properties"])
            for key, value in b.items():
                prop = schema["properties"][key]
                if key in ("params", "cov_diag"):
                    assert prop["type"] == ("object" if key == "params" else "array")
                else:
                    assert prop["type"] == "array" and len(value) == len(b["t_ns"]), (topic, key)
    assert BLOCK_TOPICS["/sensor/wrench"]["properties"]["force_S"]["items"]["maxItems"] == 3
    assert ESTIMATOR_BLOCK_SCHEMA["title"] == "hapticlab.EstimatorEstimateBlock"


@pytest.mark.parametrize("encoding", ["cdr", "json"])
def test_non_finite_values_in_a_block_read_back_as_nan(tmp_path, encoding):
    """JSON records NaN and ±inf as null, CDR as they are; the reader gives NaN for all of them either way
    (and None in the per-sample messages, as JSON's null)."""
    path = tmp_path / "nan.mcap"
    force = np.array([[1.0, NAN, 2.0], [math.inf, 0.0, -math.inf], [1, 2, 3]])
    with Recorder(path, block_encoding=encoding) as rec:
        offset = rec.clock_offset_ns
        rec.write_block(
            "/sensor/wrench",
            {
                "t_ns": np.array([10, 20, 30]),
                "force_S": force,
                "torque_S": [[0.0] * 3] * 3,
                "seq": np.arange(3),
                "status": [0, 0, 1],
            },
        )
    with open(path, "rb") as f:
        ((_, _, message),) = make_reader(f).iter_messages()
    assert message.log_time == 30 + offset  # the last sample's time, as Unix time
    if encoding == "json":
        assert json.loads(message.data)["force_S"] == [[1.0, None, 2.0], [None, 0.0, None], [1, 2, 3]]
    else:  # the values as they are, from the 4th float64 of force_S on: header, t_ns (4+4+24), count + pad
        raw = np.frombuffer(message.data, dtype="<f8", count=9, offset=4 + 32 + 8)
        assert np.array_equal(raw, force.ravel(), equal_nan=True) and np.isinf(raw[3])
    rec = read_recording(path)
    force = rec.field("/sensor/wrench", "force_S")
    assert np.array_equal(force, [[1.0, NAN, 2.0], [NAN, 0.0, NAN], [1.0, 2.0, 3.0]], equal_nan=True)
    assert rec.t_ns("/sensor/wrench").tolist() == [10, 20, 30]
    assert rec.field("/sensor/wrench", "seq").tolist() == [0, 1, 2]
    assert [m["force_S"] for _, m in rec.messages("/sensor/wrench")][:2] == [[1.0, None, 2.0], [None, 0.0, None]]


def test_blocks_out_of_order_read_back_in_time_order(tmp_path):
    path = tmp_path / "late.mcap"
    with Recorder(path) as rec:
        for start in (100, 0, 200):
            t = list(range(start, start + 30, 10))
            rec.write_block(
                "/sensor/wrench",
                {
                    "t_ns": t,
                    "force_S": [[float(x), 0.0, 0.0] for x in t],
                    "torque_S": [[0.0] * 3] * 3,
                    "seq": t,
                    "status": [0] * 3,
                },
            )
    for rec in (read_recording(path), open_recording(path)):
        t, force, _ = rec.wrench()
        assert t.tolist() == [0, 10, 20, 100, 110, 120, 200, 210, 220] and force[:, 0].tolist() == t.tolist()
        assert [m["seq"] for _, m in rec.messages("/sensor/wrench")] == t.tolist()


@pytest.mark.parametrize("encoding", ["cdr", "json"])
def test_write_block_refuses_bad_blocks(tmp_path, encoding):
    with Recorder(tmp_path / "bad.mcap", block_encoding=encoding) as rec:
        with pytest.raises(ValueError, match="one message per sample, not in blocks"):
            rec.write_block("/haptic/command", {"t_ns": [1], "force_D": [[0.0] * 3], "enabled": [True]})
        with pytest.raises(ValueError, match="unknown recording topic"):
            rec.write_block("/nope", {"t_ns": [1]})
        for t_ns in ([], [1.5], [1, 1.5, 2], np.array([1.0]), None, [-1], [1, 1 << 64]):
            with pytest.raises(ValueError, match="t_ns"):
                rec.write_block("/sensor/wrench", {"t_ns": t_ns, "force_S": []})
        rec.write(
            "/aligned/sample",
            1,
            {
                "force_S": [0.0] * 3,
                "torque_S": [0.0] * 3,
                "quat_BE": [1.0, 0, 0, 0],
                "seq": 0,
                "status": 0,
                "stale": False,
            },
        )
        with pytest.raises(ValueError, match="one layout per topic"):
            rec.write_block("/aligned/sample", {"t_ns": [2], "force_S": [[0.0] * 3]})
        rec.write_block("/estimator/rls", {"t_ns": [1], "contact_force_S": [[0.0] * 3]})
        with pytest.raises(ValueError, match="one layout per topic"):
            rec.write("/estimator/rls", 2, {"contact_force_S": [0.0] * 3})
        if encoding == "cdr":  # a block that does not fit its definition is refused when it is written
            good = {"t_ns": [1, 2], "force_S": [[0.0] * 3] * 2, "torque_S": np.zeros((2, 3)), "seq": [0, 1]}
            rec.write_block("/sensor/wrench", good)
            with pytest.raises(ValueError, match="field 'force_S' does not hold one value for each of its 2"):
                rec.write_block("/sensor/wrench", {**good, "force_S": [[0.0] * 3]})
            with pytest.raises(ValueError, match="force_S"):
                rec.write_block("/sensor/wrench", {**good, "force_S": [[0.0] * 3, [0.0]]})
            with pytest.raises(ValueError, match="has no field 'nope'"):
                rec.write_block("/sensor/wrench", {**good, "nope": [1, 2]})
            with pytest.raises(TypeError, match="'seq' must hold 64-bit integers"):
                rec.write_block("/sensor/wrench", {**good, "seq": [0.5, 1.5]})
            with pytest.raises(TypeError, match="'contact' must hold flags"):
                rec.write_block("/estimator/rls", {"t_ns": [1], "contact": ["yes"]})


def test_a_damaged_block_is_a_one_line_error(tmp_path):
    path = tmp_path / "ragged.mcap"
    with Recorder(path, block_encoding="json") as rec:
        rec.write_block(
            "/sensor/wrench",
            {"t_ns": [1, 2], "force_S": [[0.0] * 3], "torque_S": [[0.0] * 3] * 2, "seq": [0, 1], "status": [0, 0]},
        )
    for read in (
        lambda: read_recording(path),
        lambda: open_recording(path).field("/sensor/wrench", "force_S"),
        lambda: list(iter_messages(path, "/sensor/wrench")),
    ):
        with pytest.raises(RecordingError, match="field 'force_S' does not hold one value for each of its 2 samples"):
            read()


def test_a_truncated_block_recording_recovers_whole_blocks(tmp_path):
    path = tmp_path / "blocks.mcap"
    written = []
    with Recorder(path, chunk_size=2048) as rec:
        for k in range(300):
            t = [1_000_000 + 7 * k + i for i in range(7)]
            written += t
            rec.write_block(
                "/sensor/wrench",
                {
                    "t_ns": t,
                    "force_S": [[x * 0.5, -1.0, 2.0] for x in t],
                    "torque_S": [[0.0, 0.0, x * 1e-3] for x in t],
                    "seq": t,
                    "status": [0] * 7,
                },
            )
            rec.write("/haptic/command", t[-1], {"force_D": [0.0, 0.0, float(k)], "enabled": True})
    data = path.read_bytes()
    for cut in (len(data) // 4, len(data) // 2, 3 * len(data) // 4):
        broken = tmp_path / f"cut{cut}.mcap"
        broken.write_bytes(data[:cut])
        stats = recover(broken, tmp_path / f"fixed{cut}.mcap")
        rec = read_recording(tmp_path / f"fixed{cut}.mcap")
        t, force, _torque = rec.wrench()
        assert 0 < len(t) < len(written) and len(t) % 7 == 0  # whole blocks only
        assert t.tolist() == written[: len(t)]
        assert force[:, 0].tolist() == [x * 0.5 for x in t.tolist()]
        assert stats["topics"]["/sensor/wrench"] == len(t) // 7  # MCAP messages: one per block
        assert rec.blocks["/sensor/wrench"] and rec.format_version == FORMAT_VERSION


def test_a_damaged_cdr_block_is_a_one_line_error(tmp_path):
    path = tmp_path / "short.mcap"
    with Recorder(path) as rec:
        rec.write_block("/sensor/wrench", {"t_ns": [1, 2], "force_S": np.zeros((2, 3))})
    with open(path, "rb") as f:
        ((_, _, message),) = make_reader(f).iter_messages()
    cut = tmp_path / "cut.mcap"
    with Recorder(cut) as rec:  # the same channel, a message cut short inside force_S
        rec.write_block("/sensor/wrench", {"t_ns": [1], "force_S": np.zeros((1, 3))})
        rec._add_bytes(rec._block_ids["/sensor/wrench"], 2, message.data[:40])
    for read in (
        lambda: read_recording(cut),
        lambda: open_recording(cut).field("/sensor/wrench", "force_S"),
        lambda: list(iter_messages(cut, "/sensor/wrench")),
    ):
        with pytest.raises(
            RecordingError,
            match=r"cut.mcap: /sensor/wrench block message at 2 ns: force_S runs "
            r"past the end",
        ) as info:
            read()
        assert "\n" not in str(info.value)
