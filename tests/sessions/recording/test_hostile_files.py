"""A hostile MCAP is one line and exit status 2, never a traceback."""

from __future__ import annotations

import json

import pytest
from helpers import one_line_error
from mcap.writer import Writer


def deep_mcap(path, depth: int = 100_000) -> None:
    """A valid MCAP whose /sensor/wrench and /kinematics/pose messages each hold JSON nested ``depth`` deep."""
    deep = b"[" * depth + b"]" * depth
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("hapticlab.Wrench", "jsonschema", json.dumps({"type": "object"}).encode())
        for topic in ("/sensor/wrench", "/kinematics/pose"):
            channel = writer.register_channel(topic, "json", schema)
            writer.add_message(channel, log_time=1, publish_time=1, data=b'{"t_ns": 1, "force_S": ' + deep + b"}")
        writer.finish()


@pytest.mark.parametrize("command", [["compensate", "-o", "{tmp}/out.csv"], ["discrepancy"]])
def test_json_nested_100000_deep_is_bad_json_not_a_traceback(tmp_path, capsys, command):
    deep_mcap(tmp_path / "deep.mcap")
    argv = [command[0], str(tmp_path / "deep.mcap"), *(a.format(tmp=tmp_path) for a in command[1:])]
    err = one_line_error(capsys, argv)
    assert err == (
        f"hapticlab {command[0]}: error: deep.mcap: /sensor/wrench message 1 is not valid JSON "
        "(nested too deeply: line 1 column 1 (char 0))"
    )
    assert not (tmp_path / "out.csv").exists()


def bomb_mcap(path, inflated: int) -> None:
    """A valid MCAP whose one /sensor/wrench message is ``inflated`` bytes of zeros in JSON: its chunk
    compresses to a few kB."""
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("hapticlab.Wrench", "jsonschema", json.dumps({"type": "object"}).encode())
        for topic in ("/sensor/wrench", "/kinematics/pose"):
            channel = writer.register_channel(topic, "json", schema)
            writer.add_message(channel, log_time=1, publish_time=1, data=b'{"pad": "' + b"0" * inflated + b'"}')
        writer.finish()


@pytest.mark.parametrize("command", [["compensate", "-o", "{tmp}/out.csv"], ["replay", "--estimator", "rls"]])
def test_a_chunk_that_inflates_past_the_limit_is_refused_before_it_is_decompressed(
    tmp_path, capsys, monkeypatch, command
):
    """The limit (64 MiB) lowered to 1 MiB here, so that the test's file stays small: a 4 MiB chunk in a
    file of a few kB (the 26 kB file that inflated to 1.75 GB is the same shape)."""
    from hapticlab.sessions.recording import columnar, mcapfile

    monkeypatch.setattr(mcapfile, "MAX_CHUNK_BYTES", 1 << 20)
    monkeypatch.setattr(columnar, "MAX_CHUNK_BYTES", 1 << 20)
    path = tmp_path / "bomb.mcap"
    bomb_mcap(path, 4 << 20)
    assert path.stat().st_size < 64 << 10
    argv = [command[0], str(path), *(a.format(tmp=tmp_path) for a in command[1:])]
    err = one_line_error(capsys, argv)
    assert err.startswith(f"hapticlab {command[0]}: error: {path}: chunk at byte "), err
    assert err.endswith("inflates to 4 MiB (at most 1 MiB): not a recording hapticlab reads"), err
