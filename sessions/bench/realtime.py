"""A paced demo session (``realtime = true``) measured from inside: samples, overruns, latency, memory.

What ``bench/realtime.py`` runs for minutes: the latency from the newest
sample's stamp to the haptic command's send, and the resident memory of the
process (and of the MCAP writer's process) once a second. Numbers depend on
the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.live.loop import LiveLoop


def realtime_run(
    duration_s: float,
    sensor_rate_hz: float = 7000.0,
    estimator: str = "rls",
    progress: Callable[[str], None] | None = None,
    writer: str = "process",
) -> dict[str, Any]:
    """One paced (``realtime = true``) demo session: samples expected and received, overruns, the latency
    from the newest sample's stamp to the haptic command's send (µs: median, p99, max; the stamp is when a
    real sensor's sample would have arrived), and the resident memory once a second (MB) of the process
    and, with ``writer="process"``, of the writer process."""
    config, _ = load_config("demo")
    config = apply_overrides(
        config,
        [
            "session.realtime=true",
            f"sensor.rate_hz={float(sensor_rate_hz)}",
            f"estimator.name={estimator}",
            f"session.recording_writer={writer}",
        ],
    )
    session = build_session(config)
    # allocated up front (a Python list of 600,000 ints is ~22 MB the session's own memory would be blamed for)
    latencies = np.full(int(duration_s * session.settings.loop_rate_hz) + 2, -1, dtype=np.int64)  # pages touched now
    count = [0]
    rss_mb: list[float] = []
    writer_rss_mb: list[float] = []
    with tempfile.TemporaryDirectory() as folder:
        loop = LiveLoop(session, Path(folder) / "realtime.mcap", duration_s, None, 0.25)
        send = session.haptic.send
        clock = time.monotonic_ns
        next_rss = [0]

        def timed_send(command):
            send(command)
            now = clock()
            newest = loop.gate.last_sample_ns
            if newest is not None and count[0] < len(latencies):
                latencies[count[0]] = now - newest
                count[0] += 1
            if now >= next_rss[0]:
                next_rss[0] = now + 1_000_000_000
                rss_mb.append(_rss_mb())
                if loop.recorder.writer_pid is not None:
                    writer_rss_mb.append(_rss_mb(loop.recorder.writer_pid))
                if progress:
                    progress(f"realtime, {(now - loop.t0_ns) * 1e-9:.0f} of {duration_s:g} s")

        session.haptic.send = timed_send  # type: ignore[method-assign]  # the bench times every command sent
        result = loop.run()
        size_mb = result.path.stat().st_size / 1e6
    lat = latencies[: count[0]] / 1e3
    return {
        "duration_s": duration_s,
        "sensor_rate_hz": sensor_rate_hz,
        "estimator": estimator,
        "samples_expected": int(duration_s * sensor_rate_hz),
        "samples": result.samples,
        "overruns": result.overruns,
        "ticks": count[0],
        "latency_us": {"median": float(np.median(lat)), "p99": float(np.percentile(lat, 99)), "max": float(lat.max())},
        "rss_mb": {"first": rss_mb[0], "last": rss_mb[-1], "peak": max(rss_mb)},
        "recording_mb": size_mb,
        "writer": writer,
        "writer_rss_mb": (
            {"first": writer_rss_mb[0], "last": writer_rss_mb[-1], "peak": max(writer_rss_mb)}
            if writer_rss_mb
            else None
        ),
    }


def _rss_mb(pid: int | str = "self") -> float:
    """A process's resident memory now, MB (``VmRSS`` of /proc/PID/status; this process by default)."""
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")
