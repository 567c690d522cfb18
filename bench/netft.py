"""The ``netft`` sensor's two RDT receivers against the emulator at 7 kHz: read cost per sample, paced-session overruns.

Run: ``.venv/bin/python bench/netft.py [READ_SECONDS] [SESSION_SECONDS]`` (default 5 and 8). The emulator runs in
its own process (as a real sensor would be another machine), on 127.0.0.150, streaming at 7000 Hz.

1. ``read()`` alone, called once per millisecond (paced by sleeping to the next one) for READ_SECONDS: per tick,
   the read's cost divided by the samples it returned, µs per sample (median and p99 over the ticks that returned
   samples), and the samples received against those sent.
2. A paced demo session (``session.realtime = true``, 1 kHz loop, sensor ``netft`` against the emulator,
   kinematics ``sim``, ``stale_timeout = 0.005``) for SESSION_SECONDS with each receiver, and with the ``sim``
   sensor at 7 kHz for reference: the loop's overruns (ticks later than a period) and the samples read.

Not a test: numbers move with the machine's load (quote ``uptime`` with them). Prints a table.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hapticlab.plugins.sensors.netft import NetFTSensor
from hapticlab.sessions.config import load_config
from hapticlab.sessions.live.build import build_session
from hapticlab.sessions.live.loop import run_session

ADDRESS = "127.0.0.150"
RECEIVERS = ("hapticlab", "pynetft")


class Emulator:
    """``hapticlab emulate netft`` in a child process on ADDRESS with ports the kernel picks."""

    def __init__(self, seconds: float):
        code = (
            "import sys; from hapticlab.sessions.cli import main; sys.exit(main(['emulate', 'netft', *sys.argv[1:]]))"
        )
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-c",
                code,
                "--address",
                ADDRESS,
                "--rdt-port",
                "0",
                "--http-port",
                "0",
                "--duration",
                f"{seconds:g}",
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        first = self.process.stdout.readline()  # "netft emulator on ADDRESS: RDT udp/PORT, netftapi2.xml http/PORT"
        self.rdt_port = int(first.split("udp/")[1].split(",")[0])
        self.http_port = int(first.split("http/")[1])

    def close(self) -> str:
        """Stop it; its last line (what it sent)."""
        self.process.terminate()
        out, _ = self.process.communicate(timeout=10)
        return out.strip().splitlines()[-1] if out.strip() else ""


def read_cost(receiver: str, seconds: float) -> dict:
    """µs per sample of ``read()`` (per tick: cost / samples), median and p99, and the samples read."""
    emulator = Emulator(seconds + 10)
    try:
        sensor = NetFTSensor(ADDRESS, emulator.rdt_port, emulator.http_port, receiver=receiver)
        sensor.open(time.monotonic_ns())
        per_sample_us, total = [], 0
        start = time.monotonic_ns()
        tick_ns = start
        while tick_ns - start < seconds * 1e9:
            tick_ns += 1_000_000
            delay = (tick_ns - time.monotonic_ns()) * 1e-9
            if delay > 0:
                time.sleep(delay)
            t0 = time.perf_counter_ns()
            samples = sensor.read(time.monotonic_ns())
            cost = time.perf_counter_ns() - t0
            if samples:
                per_sample_us.append(cost / len(samples) / 1e3)
                total += len(samples)
        health = sensor.health_counters()
        sensor.close()
    finally:
        emulator.close()
    us = np.array(per_sample_us)
    return {
        "median_us": float(np.median(us)),
        "p99_us": float(np.percentile(us, 99)),
        "samples": total,
        "per_s": total / seconds,
        "lost": health["lost"],
        "reconnect": health["reconnect"],
    }


def session_overruns(sensor: str, seconds: float) -> dict:
    """A paced 1 kHz demo session with a 7 kHz sensor: overruns and samples."""
    config = load_config("demo")[0]
    config["session"] = dict(config["session"], duration=seconds, realtime=True, stale_timeout=0.005)
    emulator = None
    if sensor == "sim":
        config["sensor"] = {"name": "sim", "rate_hz": 7000.0}
    else:
        emulator = Emulator(seconds + 30)
        config["sensor"] = {
            "name": "netft",
            "address": ADDRESS,
            "rdt_port": emulator.rdt_port,
            "http_port": emulator.http_port,
            "receiver": sensor,
            "rate_hz": 7000.0,
        }
    try:
        with tempfile.TemporaryDirectory() as folder:
            result = run_session(build_session(config), out=Path(folder) / "netft.mcap")
    finally:
        if emulator is not None:
            emulator.close()
    return {"overruns": result.overruns, "samples": result.samples, "per_s": result.samples / result.duration_s}


def main() -> None:
    read_s = float(sys.argv[1]) if len(sys.argv) > 1 else 5.0
    session_s = float(sys.argv[2]) if len(sys.argv) > 2 else 8.0
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores shared)", flush=True)
    reads = {r: read_cost(r, read_s) for r in RECEIVERS}
    sessions = {s: session_overruns(s, session_s) for s in (*RECEIVERS, "sim")}
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    print(f"\nread() at 7 kHz, {read_s:g} s, one read per ms")
    print("| receiver | µs/sample median | p99 | samples/s | lost | reconnect |")
    print("|---|---|---|---|---|---|")
    for r, x in reads.items():
        print(f"| {r} | {x['median_us']:.1f} | {x['p99_us']:.1f} | {x['per_s']:.0f} | {x['lost']} | {x['reconnect']} |")
    print(f"\npaced demo session, 1 kHz loop, 7 kHz sensor, {session_s:g} s")
    print("| sensor | overruns | samples/s |")
    print("|---|---|---|")
    for s, x in sessions.items():
        label = f"netft, {s}" if s != "sim" else "sim (reference)"
        print(f"| {label} | {x['overruns']} | {x['per_s']:.0f} |")


if __name__ == "__main__":
    main()
