"""Sensor sample → force bytes on the master's wire, and fault → zero force on the wire, through a real session.

    .venv/bin/python bench/haptic_wire.py [--faults 100] [--stalls 10] [--protocol hapticlab|inverse3]

What runs: ``hapticlab emulate master --log-forces`` in a process of its own (a
serial master on a pseudo-terminal that notes, for every force frame, when it
came off the wire: ``time.monotonic_ns()`` right after its ``read``), and a
realtime 1 kHz session in this process (the demo's simulated robot and
sensor, ``rls``, recording on) whose haptic output is the ``serial`` plugin
on that pty. The tool presses one long contact (3 N) while faults are
injected into the sensor's stream, one every 0.4 s:

* ``sensor_nan``, ``sensor_saturated`` and a 500 N ``sensor_spike`` (beyond
  the sensor's range: implausible), in turn, ``--faults`` of them, 30 ms
  each: the gate must zero the force at the first bad sample;
* then ``--stalls`` ``sensor_dropout``s (no samples at all, 100 ms): there is
  no bad sample to see, only silence, so the zero comes ``session.stale_timeout``
  after the last good sample; measured separately.

Every /haptic/command the session recorded is matched, in order, to the
frame the device received (the forces must agree to the last float32 bit,
or the bench stops). Then:

* **latency**: for every command carrying a force from an estimate,
  receipt time − the stamp of the sensor sample behind it
  (``HapticCommand.source_t_ns``; the simulated sensor's sample ``i`` is
  stamped ``t0 + i`` ms and becomes readable at that instant, so the stamp
  is when the sample existed). Split into sample → the tick's start and the
  tick's start → on the wire;
* **fault → zero**: from the stamp of the first bad sample of each fault
  (found in the recording: NaN, saturation bit, beyond range) to the
  receipt of the first zero force after it, against the device period
  (one command per loop period, 1 ms).

Both run with the serial plugin waiting for each reply (the default) and
pipelined (``wait_for_reply = false``). A pty has no baud rate: over a real
UART add the frame's bytes (19 bytes, 0.19 ms at 1 Mbit/s). Numbers vary with
the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hapticlab.core.types import STATUS_OK
from hapticlab.sessions.config import load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.live.build import stale_timeout_ns
from hapticlab.sessions.recording import open_recording

EMULATOR = (
    "import argparse, sys; from hapticlab.plugins.haptics import master_emulator_cli as m; "
    "p = argparse.ArgumentParser(); m.add_arguments(p); sys.exit(m.run(p.parse_args(sys.argv[1:])))"
)
FAULT_KINDS = ("sensor_nan", "sensor_saturated", "sensor_spike")
FIRST_FAULT_S = 10.0  # the estimator has converged and the contact is on
SPACING_S = 0.4
FAULT_S = 0.03
STALL_S = 0.1


def config(port: str, protocol: str, wait_for_reply: bool, faults: int, stalls: int) -> tuple[dict, float]:
    """The demo session on the serial master, one long contact, the faults; and its duration, s."""
    cfg, _ = load_config("demo")
    n = faults + stalls
    duration = FIRST_FAULT_S + n * SPACING_S + 1.0
    cfg["session"]["duration"] = duration
    cfg["world"]["contacts"] = [
        {"kind": "indentation", "start": 6.0, "duration": duration, "peak_force": 3.0, "ramp": 0.3}
    ]
    cfg["world"]["faults"] = [
        {
            "kind": FAULT_KINDS[i % len(FAULT_KINDS)],
            "start": FIRST_FAULT_S + i * SPACING_S,
            "duration": FAULT_S,
            **({"force": [500.0, 0.0, 0.0]} if FAULT_KINDS[i % len(FAULT_KINDS)] == "sensor_spike" else {}),
        }
        for i in range(faults)
    ]
    cfg["world"]["faults"] += [
        {"kind": "sensor_dropout", "start": FIRST_FAULT_S + (faults + i) * SPACING_S, "duration": STALL_S}
        for i in range(stalls)
    ]
    cfg["haptic"] = {
        **cfg["haptic"],
        "name": "serial",
        "port": port,
        "protocol": protocol,
        "wait_for_reply": wait_for_reply,
        "device_max_force": 8.0,
    }
    return cfg, duration


def received(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The emulator's log: (N,) receipt times, ns, and (N, 3) float32 forces, N."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))[1:]
    return (
        np.array([int(r[0]) for r in rows], np.int64),
        np.array([[float(x) for x in r[1:]] for r in rows], np.float32),
    )


def percentiles(x: np.ndarray) -> str:
    return f"p50 {np.percentile(x, 50):7.3f}  p99 {np.percentile(x, 99):7.3f}  max {x.max():7.3f} ms  (n={len(x)})"


def measure(protocol: str, wait_for_reply: bool, faults: int, stalls: int, tmp: Path) -> dict:
    label = f"{protocol}, {'waits for each reply' if wait_for_reply else 'pipelined'}"
    log = tmp / f"received-{protocol}-{wait_for_reply}.csv"
    proc = subprocess.Popen(
        [sys.executable, "-c", EMULATOR, "--protocol", protocol, "--path", "hold", "--log-forces", str(log)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = proc.stdout.readline().strip()
        cfg, duration = config(port, protocol, wait_for_reply, faults, stalls)
        print(f"{label}: {duration:.0f} s realtime session on {port} ...", flush=True)
        result = run_session(build_session(cfg), tmp / f"wire-{protocol}-{wait_for_reply}.mcap")
    finally:
        proc.terminate()
        proc.wait(10)
    t_rx, f_rx = received(log)
    rec = open_recording(result.path)
    force_D = rec.field("/haptic/command", "force_D").astype(np.float32)
    t_cmd = rec.t_ns("/haptic/command")
    source_f = rec.field("/haptic/command", "source_t_ns").astype(float)  # null (a zero command) reads NaN
    enabled = rec.field("/haptic/command", "enabled").astype(bool)
    n = len(force_D)  # then the plugin's close() writes one more zero, unrecorded
    if len(t_rx) < n or not np.array_equal(f_rx[:n], force_D) or np.any(f_rx[n:]):
        raise SystemExit(
            f"{label}: {n} commands recorded, {len(t_rx)} frames received, and they do not match "
            "one to one: the latencies would be meaningless"
        )
    t_rx, f_rx = t_rx[:n], f_rx[:n]
    on = enabled & np.isfinite(source_f)
    source = np.where(on, source_f, 0).astype(np.int64)  # ns since boot < 2**53: exact in a float
    total = (t_rx[on] - source[on]) / 1e6
    to_tick = (t_cmd[on] - source[on]) / 1e6
    to_wire = (t_rx[on] - t_cmd[on]) / 1e6

    t_s = rec.t_ns("/sensor/wrench")
    f_s = rec.field("/sensor/wrench", "force_S")
    status = rec.field("/sensor/wrench", "status").astype(int)
    bad = ~np.isfinite(f_s).all(axis=1) | (status != STATUS_OK) | (np.abs(f_s) > 400.0).any(axis=1)
    onsets = t_s[1:][bad[1:] & ~bad[:-1]]
    zero = ~np.any(f_rx, axis=1)
    fault_ms, force_before = [], []
    for t in onsets:
        after = np.flatnonzero((t_rx >= t) & zero)
        before = np.flatnonzero(t_rx < t)
        fault_ms.append((t_rx[after[0]] - t) / 1e6)
        force_before.append(np.linalg.norm(f_rx[before[-1]]))
    stall_ms = []
    gap = np.diff(t_s) > STALL_S * 0.5e9
    for t_last in t_s[:-1][gap]:  # the last good sample before each silence
        after = np.flatnonzero((t_rx > t_last) & zero)
        stall_ms.append((t_rx[after[0]] - t_last) / 1e6)
    return {
        "label": label,
        "total": total,
        "to_tick": to_tick,
        "to_wire": to_wire,
        "fault_ms": np.array(fault_ms),
        "force_before": np.array(force_before),
        "stall_ms": np.array(stall_ms),
        "stale_timeout_ms": stale_timeout_ns(
            cfg["session"].get("stale_timeout", 0.0), cfg["sensor"]["rate_hz"], cfg["session"]["loop_rate_hz"]
        )
        / 1e6,
        "overruns": sum(e.kind == "overrun" for e in rec.events),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faults", type=int, default=100, help="bad-sample faults injected (default 100)")
    parser.add_argument("--stalls", type=int, default=10, help="sensor stalls injected after them (default 10)")
    parser.add_argument("--protocol", choices=("hapticlab", "inverse3"), default="hapticlab")
    args = parser.parse_args()
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; {time.strftime('%Y-%m-%d %H:%M')}",
        flush=True,
    )
    with tempfile.TemporaryDirectory() as tmp:
        runs = [measure(args.protocol, wait, args.faults, args.stalls, Path(tmp)) for wait in (True, False)]
    period_ms = 1.0
    for r in runs:
        print(f"\n{r['label']} ({r['overruns']} overrun event(s))")
        print(f"  sensor sample → force on the wire  {percentiles(r['total'])}")
        print(f"    sample → the tick's start        {percentiles(r['to_tick'])}")
        print(f"    tick's start → on the wire       {percentiles(r['to_wire'])}")
        f = r["fault_ms"]
        print(
            f"  fault → zero on the wire, {len(f)} faults ({', '.join(FAULT_KINDS)}): "
            f"p50 {np.median(f):.3f}  worst {f.max():.3f} ms; within one device period ({period_ms:g} ms): "
            f"{np.count_nonzero(f <= period_ms)}/{len(f)}; force on the wire just before: "
            f"{r['force_before'].min():.2f}–{r['force_before'].max():.2f} N"
        )
        s = r["stall_ms"]
        if len(s):
            print(
                f"  sensor stall → zero on the wire, {len(s)} stalls (from the last sample; stale timeout "
                f"{r['stale_timeout_ms']:g} ms): p50 {np.median(s):.3f}  worst {s.max():.3f} ms"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
