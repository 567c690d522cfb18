"""Helper for test_recording: records at ~1 kHz until it is killed.

Usage: python _crashing_writer.py OUT.mcap FLUSH_INTERVAL_S CHUNK_SIZE KILL_AT TICKS.txt [blocks | json-blocks]
[process] [group]

With a CHUNK_SIZE far larger than 3 s of data, only the time-based flush puts
messages on disk.

Prints "ready" once the recorder is open, then writes until tick KILL_AT: per tick one
/sensor/wrench message whose values are a function of its seq (so the test can
check every salvaged message), one /aligned/sample every 2nd tick, an event
every 250th tick, and from 1 s on an /estimator/late channel (registered
mid-file). Timestamps are time.monotonic_ns() (CLOCK_MONOTONIC, shared with
the parent process).

With ``blocks`` (format 3, CDR, as a live session at 7 kHz) or ``json-blocks``
(format 2), each tick writes /sensor/wrench and /aligned/sample as one block of
7 samples (seq 7·tick to 7·tick + 6) and, from 1 s on, /estimator/late as a
block with params.

With ``process`` the recorder's ``mcap`` writer runs in its child process
(``writer="process"``, as a live session's does) and each tick is one ``send``;
"ready" is followed by the child's pid on the same line.

At tick KILL_AT, before writing it, the helper writes the stamps of the tick
before and of this one to TICKS.txt, then SIGKILLs itself (``group``: its
process group, the writer process with it: a power cut), as a kill from outside
would, at a tick the test knows.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

from hapticlab.sessions.recording import Recorder


def wrench(i: int) -> dict:
    return {"force_S": [i * 0.5, -i * 0.25, i * 1e-3], "torque_S": [i * 1e-4, 2.0, -3.0], "seq": i, "status": i % 3}


def write_blocks(rec: Recorder, t: int, tick: int, late: bool) -> None:
    seqs = range(7 * tick, 7 * tick + 7)
    times = [t - 1000 * (6 - k) for k in range(7)]  # 1 µs apart, the last at t
    samples = [wrench(s) for s in seqs]
    rec.write_block("/sensor/wrench", {"t_ns": times, **{k: [w[k] for w in samples] for k in samples[0]}})
    rec.write_block(
        "/aligned/sample",
        {
            "t_ns": times,
            "force_S": [w["force_S"] for w in samples],
            "torque_S": [w["torque_S"] for w in samples],
            "quat_BE": [[1.0, 0.0, 0.0, 0.0]] * 7,
            "seq": list(seqs),
            "status": [0] * 7,
            "stale": [False] * 7,
        },
    )
    if tick % 250 == 0:
        rec.event(t, "tick", f"tick {tick}", seq=tick)
    if late:
        rec.write_block(
            "/estimator/late",
            {
                "t_ns": times,
                "contact_force_S": [[0.0] * 3] * 7,
                "contact_torque_S": [[0.0] * 3] * 7,
                "contact": [False] * 7,
                "converged_force": [True] * 7,
                "converged_torque": [False] * 7,
                "params": {"seq": [float(seqs[-1])]},
                "cov_diag": [1.0],
            },
        )


def main() -> None:
    path, flush_interval, chunk_size = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
    kill_at, ticks = int(sys.argv[4]), Path(sys.argv[5])
    options = sys.argv[6:]
    process = "process" in options
    blocks = "blocks" in options or "json-blocks" in options
    rec = Recorder(
        path,
        {"hapticlab.session": {"config": {"preset": "crash-test"}}, "hapticlab.calibration": {"counts_per_force": 1e6}},
        flush_interval_s=flush_interval,
        chunk_size=chunk_size,
        overwrite=True,
        block_encoding="json" if "json-blocks" in options else "cdr",
        writer="process" if process else "inline",
    )
    print("ready", rec.writer_pid or "", flush=True)
    t0 = previous = time.monotonic_ns()
    i = 0
    while True:
        t = time.monotonic_ns()
        if i == kill_at:
            ticks.write_text(f"{previous} {t}")
            os.killpg(0, signal.SIGKILL) if "group" in options else os.kill(os.getpid(), signal.SIGKILL)
        previous = t
        if blocks:
            write_blocks(rec, t, i, t - t0 > 1_000_000_000)
            rec.send()
            i += 1
            delay = (t0 + i * 1_000_000 - time.monotonic_ns()) * 1e-9
            if delay > 0:
                time.sleep(delay)
            continue
        rec.write("/sensor/wrench", t, wrench(i))
        if i % 2 == 0:
            rec.write(
                "/aligned/sample",
                t,
                {
                    "force_S": [i * 0.5, 0.0, 0.0],
                    "torque_S": [0.0, 0.0, 0.0],
                    "quat_BE": [1.0, 0.0, 0.0, 0.0],
                    "seq": i,
                    "status": 0,
                    "stale": False,
                },
            )
        if i % 250 == 0:
            rec.event(t, "tick", f"tick {i}", seq=i)
        if t - t0 > 1_000_000_000:
            rec.write(
                "/estimator/late",
                t,
                {
                    "contact_force_S": [0.0, 0.0, 0.0],
                    "contact_torque_S": [0.0, 0.0, 0.0],
                    "contact": False,
                    "converged_force": True,
                    "converged_torque": False,
                    "params": {"seq": [float(i)]},
                    "cov_diag": [1.0],
                },
            )
        rec.send()
        i += 1
        delay = (t0 + i * 1_000_000 - time.monotonic_ns()) * 1e-9
        if delay > 0:
            time.sleep(delay)


if __name__ == "__main__":
    main()
