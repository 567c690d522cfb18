"""The live view: a running session served to Foxglove over WebSocket by the recording's writer process."""

from __future__ import annotations

import asyncio
import json
import struct
import threading
import time

import pytest
from mcap.reader import make_reader

from hapticlab.core.host.registry import ConfigError
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import read_recording

pytest.importorskip("foxglove", reason="the live extra (foxglove-sdk) is not installed")
websockets = pytest.importorskip("websockets")


def demo(duration: float, *overrides: str):
    config, _ = load_config("demo")
    return apply_overrides(config, [f"session.duration={duration}", *overrides])


async def watch(address: str, seconds: float) -> tuple[dict, list[tuple[int, int, bytes]]]:
    """Connect as Foxglove does, subscribe to every channel, collect (channel id, log time, payload)."""
    async with websockets.connect(f"ws://{address}", subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: dict[int, dict] = {}
        received: list[tuple[int, int, bytes]] = []
        subscriptions: dict[int, int] = {}
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while loop.time() < end:
            try:
                message = await asyncio.wait_for(ws.recv(), timeout=max(end - loop.time(), 0.01))
            except TimeoutError:
                break
            if isinstance(message, str):
                op = json.loads(message)
                if op["op"] == "advertise":
                    new = [c for c in op["channels"] if c["id"] not in channels]
                    channels.update({c["id"]: c for c in new})
                    for c in new:
                        subscriptions[len(subscriptions) + 1] = c["id"]
                    await ws.send(
                        json.dumps(
                            {
                                "op": "subscribe",
                                "subscriptions": [
                                    {"id": sid, "channelId": cid}
                                    for sid, cid in subscriptions.items()
                                    if cid in {c["id"] for c in new}
                                ],
                            }
                        )
                    )
            elif message[0] == 0x01:  # message data: opcode, subscription id, log time, payload
                sid, log_time = struct.unpack_from("<IQ", message, 1)
                received.append((subscriptions[sid], log_time, bytes(message[13:])))
        return channels, received


def test_a_running_session_is_served_live_with_the_recording_s_topics_and_bytes(tmp_path, paced_run):
    address: dict[str, str] = {}
    ready = threading.Event()

    def on_status(status):
        if status.live_address and not ready.is_set():
            address["value"] = status.live_address
            ready.set()

    result: dict = {}
    session = build_session(demo(4.0))
    runner = threading.Thread(
        target=lambda: result.update(
            r=paced_run(
                session, tmp_path / "live.mcap", on_status=on_status, status_interval_s=0.05, live="127.0.0.63:0"
            )
        )
    )
    runner.start()
    try:
        assert ready.wait(30), "the session never reported its live view"
        channels, received = asyncio.run(watch(address["value"], 2.5))
    finally:
        runner.join(60)
    rec = read_recording(result["r"].path)
    topics = {c["topic"]: c for c in channels.values()}
    assert {
        "/sensor/wrench",
        "/kinematics/pose",
        "/aligned/sample",
        "/estimator/rls",
        "/haptic/command",
        "/events",
    } <= set(topics)
    assert topics["/sensor/wrench"]["encoding"] == "cdr" and topics["/sensor/wrench"]["schemaEncoding"] == "ros2msg"
    assert topics["/haptic/command"]["encoding"] == "json"
    offset = int(rec.metadata["hapticlab.session"]["clock_offset_ns"])
    assert abs(received[0][1] - time.time_ns()) < 3600 * 10**9  # served in Unix time, as the file holds it
    by_topic: dict[str, list[tuple[int, bytes]]] = {}
    for channel_id, log_time, payload in received:  # on the session clock, as the reader gives it
        by_topic.setdefault(channels[channel_id]["topic"], []).append((log_time - offset, payload))
    commands = by_topic["/haptic/command"]
    recorded = dict(rec.topics["/haptic/command"])
    # every command the file holds over the span watched was served, in order (one a tick: the span is the
    # recording's, however long the machine took to serve it)
    served = [t for t, _ in commands]
    assert served == [t for t in recorded if served[0] <= t <= served[-1]] and len(served) > 1000
    t, payload = commands[len(commands) // 2]
    assert json.loads(payload) == recorded[t]  # the same message the file holds, at the same time
    with open(result["r"].path, "rb") as f:  # the CDR blocks: byte for byte the file's messages
        in_file = {
            message.log_time - offset: message.data
            for _, _, message in make_reader(f).iter_messages(topics=["/sensor/wrench"])
        }
    live_blocks = by_topic["/sensor/wrench"]
    blocks_t = [t for t, _ in live_blocks]  # one block per hand-over (20 ms): every one of the span watched
    assert blocks_t == [t for t in sorted(in_file) if blocks_t[0] <= t <= blocks_t[-1]] and len(blocks_t) > 100
    assert sum(struct.unpack_from("<I", block, 4)[0] for _, block in live_blocks) > 2000  # ~1 kHz of samples
    assert all(in_file[t] == block for t, block in live_blocks)


def test_a_live_address_in_use_is_one_line_and_leaves_no_file(tmp_path):
    import socket

    taken = socket.socket()
    taken.bind(("127.0.0.64", 0))
    taken.listen()
    port = taken.getsockname()[1]
    try:
        with pytest.raises(ConfigError, match=rf"--live 127.0.0.64:{port}: the live view did not start"):
            run_session(
                build_session(demo(1.0, "session.realtime=false")), out=tmp_path / "x.mcap", live=f"127.0.0.64:{port}"
            )
    finally:
        taken.close()
    assert not (tmp_path / "x.mcap").exists()
    with pytest.raises(ConfigError, match=r"--live 'nowhere': expected HOST:PORT"):
        run_session(build_session(demo(1.0, "session.realtime=false")), out=tmp_path / "y.mcap", live="nowhere")
