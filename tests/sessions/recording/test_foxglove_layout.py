"""The Foxglove layout shipped in docs/ names only topics and fields a session records (it cannot go stale), plots
the primary estimator every preset records, and draws the review's force limit."""

from __future__ import annotations

import json
import re

from helpers import ROOT
from mcap.reader import make_reader

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.review import DEFAULT_FORCE_LIMIT_N

LAYOUT = ROOT / "docs" / "foxglove-layout.json"
PRESETS = sorted(p.stem for p in (ROOT / "sessions" / "presets").glob("*.toml"))
PATH = re.compile(r"^(?P<topic>/[A-Za-z0-9_/]+)(?:\{(?P<filter>[^}]*)\})?(?:\.(?P<field>[A-Za-z_][A-Za-z0-9_]*))?")


def panel_ids(node) -> list[str]:
    return [node] if isinstance(node, str) else panel_ids(node["first"]) + panel_ids(node["second"])


def message_paths(config: dict) -> list[str]:
    paths = [p["value"] for p in config.get("paths", [])]
    return paths + ([config["topicPath"]] if "topicPath" in config else [])


def test_every_path_in_the_layout_is_a_recorded_topic_and_field(tmp_path):
    layout = json.loads(LAYOUT.read_text())
    assert sorted(panel_ids(layout["layout"])) == sorted(layout["configById"])
    config, _ = load_config("demo")
    path = tmp_path / "demo.mcap"
    run_session(build_session(apply_overrides(config, ["session.realtime=false", "session.duration=1"])), out=path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        fields: dict[str, set[str]] = {}
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            if schema.encoding == "ros2msg":  # field names from the message definition
                fields[channel.topic] = {
                    line.split()[1] for line in schema.data.decode().splitlines() if line and not line.startswith("#")
                }
            else:  # JSON: the keys of the schema's properties
                fields[channel.topic] = set(json.loads(schema.data)["properties"])
    primary = _session(path)["estimator"]  # the session's estimator, the one the haptic output follows
    checked = 0
    estimators: set[str] = set()
    references: dict[str, list[float]] = {}
    for panel, panel_config in layout["configById"].items():
        assert "foxglovePanelTitle" in panel_config, panel
        for text in message_paths(panel_config):
            if _is_number(text):  # Foxglove draws a path that is a number as a horizontal line at that value
                references.setdefault(panel, []).append(float(text))
                continue
            m = PATH.match(text)
            assert m and m["topic"] in fields, (panel, text)
            if m["field"]:
                assert m["field"] in fields[m["topic"]], (panel, text, sorted(fields[m["topic"]]))
            if m["filter"]:
                name = m["filter"].split("==")[0]
                assert name in fields[m["topic"]], (panel, text)
            if m["topic"].startswith("/estimator/"):
                estimators.add(m["topic"])
            checked += 1
    assert checked >= 15
    assert layout["configById"]["3D!tool"]["topics"] == {"/tf": {"visible": True}} and "/tf" in fields
    # every estimator panel plots the primary (the one driving the haptic output), whichever preset recorded
    assert estimators == {f"/estimator/{primary}"}
    assert {load_config(name)[0]["estimator"]["name"] for name in PRESETS} == {primary}
    # the contact force panel draws the review's default force limit (the limit a review counts time above)
    assert references == {"Plot!contact": [DEFAULT_FORCE_LIMIT_N]}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _session(path) -> dict[str, str]:
    with open(path, "rb") as f:
        return next(r.metadata for r in make_reader(f).iter_metadata() if r.name == "hapticlab.session")
