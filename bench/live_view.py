"""What the live view (``hapticlab run --live``) costs the loop: the same session with it off and on.

    .venv/bin/python bench/live_view.py [--duration 20] [--runs 3] [--rate 1000]

Runs the demo session non-realtime (as fast as the machine allows, so the wall
time per tick is the loop's own cost) ``--runs`` times each way, interleaved:
without a live view, and with one on loopback and a Foxglove WebSocket client
(``websockets``, in a process of its own, as Foxglove is) subscribed to every
channel, receiving every message. Then
the same in real time: loop overruns and the recording's tick-to-tick
intervals. The live view is served by the recording's writer process, so
the loop should not pay for it; the writer's extra work lands on the other
core. Numbers vary with the machine and its load (printed): quote them,
never assert them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.recording import read_recording


def _watch(address: str, done, count) -> None:
    """The client process: subscribe to every channel, count the messages until ``done`` is set."""
    import websockets

    async def run() -> None:
        async with websockets.connect(f"ws://{address}", subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
            subscribed: set[int] = set()
            while not done.is_set():
                try:
                    message = await asyncio.wait_for(ws.recv(), timeout=0.2)
                except TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    break
                if isinstance(message, str):
                    op = json.loads(message)
                    if op["op"] == "advertise":
                        new = [c["id"] for c in op["channels"] if c["id"] not in subscribed]
                        subscribed.update(new)
                        await ws.send(
                            json.dumps({"op": "subscribe", "subscriptions": [{"id": c, "channelId": c} for c in new]})
                        )
                else:
                    count.value += 1

    asyncio.run(run())


class Client:
    """A Foxglove WebSocket client in a process of its own (as Foxglove is): counts what arrives."""

    def __init__(self):
        context = multiprocessing.get_context("spawn")
        self.done = context.Event()
        self.count = context.Value("q", 0)
        self.context = context
        self.process = None

    def on_status(self, status) -> None:
        if status.live_address and self.process is None:
            self.process = self.context.Process(
                target=_watch, args=(status.live_address, self.done, self.count), daemon=True
            )
            self.process.start()

    @property
    def messages(self) -> int:
        return self.count.value

    def stop(self) -> None:
        self.done.set()
        if self.process is not None:
            self.process.join(10)


def one_run(duration: float, rate: float, realtime: bool, live: bool, folder: Path, k: int) -> dict:
    config, _ = load_config("demo")
    config = apply_overrides(
        config,
        [
            f"session.duration={duration}",
            f"session.realtime={str(realtime).lower()}",
            f"sensor.rate_hz={rate}",
            f"session.loop_rate_hz={min(rate, 1000.0)}",
        ],
    )
    session = build_session(config)
    client = Client() if live else None
    out = folder / f"{'live' if live else 'off'}-{'rt' if realtime else 'fast'}-{k}.mcap"
    t0 = time.perf_counter()
    result = run_session(
        session,
        out=out,
        live="127.0.0.65:0" if live else "",
        on_status=client.on_status if client else None,
        status_interval_s=0.05,
    )
    wall = time.perf_counter() - t0
    if client:
        client.stop()
    rec = read_recording(out)
    ticks = rec.t_ns("/haptic/command")[:-1]
    return {
        "wall_s": wall,
        "ticks": len(ticks),
        "us_per_tick": wall / len(ticks) * 1e6,
        "overruns": result.overruns,
        "interval_ms": np.diff(ticks) * 1e-6,
        "received": client.messages if client else 0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rate", type=float, default=1000.0, help="sensor rate, Hz")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for realtime in (False, True):
            rows = {False: [], True: []}
            for k in range(args.runs):
                for live in (False, True):
                    rows[live].append(one_run(args.duration, args.rate, realtime, live, folder, k))
            kind = "realtime" if realtime else "non-realtime (as fast as it goes)"
            print(f"\n{kind}, demo at {args.rate:g} Hz, {args.duration:g} s, {args.runs} runs each, interleaved")
            for live in (False, True):
                r = rows[live]
                us = [x["us_per_tick"] for x in r]
                intervals = np.concatenate([x["interval_ms"] for x in r])
                line = (
                    f"  live view {'on ' if live else 'off'}: {np.median(us):7.1f} µs/tick (median of runs; "
                    f"{min(us):.1f}–{max(us):.1f}), overruns {[x['overruns'] for x in r]}"
                )
                if realtime:
                    line += (
                        f", tick interval p50 {np.median(intervals):.3f} p99 {np.percentile(intervals, 99):.3f} "
                        f"max {intervals.max():.2f} ms"
                    )
                if live:
                    line += f", messages received by the client {[x['received'] for x in r]}"
                print(line)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
