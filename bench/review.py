"""How long a review takes, and how much memory: one long session, and a cohort with one and two workers.

    .venv/bin/python bench/review.py [--minutes 15] [--cohort 100] [--fast-minutes 3] [--cache DIR]

Sessions are the demo (1 kHz, ``rls``, recording on) run non-realtime for the
given length, once, into ``--cache`` (kept between runs: a 15-minute one takes
~7 minutes to make here). Each measurement runs in a fresh Python process so
its peak memory (``ru_maxrss``) is its own:

* one session: ``review`` read a chunk at a time as columns (the default) and
  a message at a time (the reference reader, every format), without plots and
  with them (the haptic commands read, the envelopes filled), then the HTML
  page and the four PNGs drawn;
* memory: the same review of a 1-minute session, of the long one and of a
  ``--fast-minutes`` 7 kHz one (flat: the pass holds a few chunks of samples,
  never the file);
* a cohort: ``--cohort`` recordings in a folder, hard links to the long
  session (the review's work per file does not depend on what is in it; the
  links share one file in the page cache, so this measures the work, not the
  disk), through ``review_folder`` (``hapticlab review DIR/``) with one and
  with two local workers: wall time (the Dask cluster's start included),
  speed-up, and each worker's peak memory.

Numbers vary with the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REVIEW = """
import json, resource, sys, time
from hapticlab.sessions.review import review
from hapticlab.sessions.review.report import session_page
t = time.perf_counter()
r = review(sys.argv[1], plots=sys.argv[2] == "plots", fast=sys.argv[3] == "fast")
wall = time.perf_counter() - t
page = 0.0
if sys.argv[2] == "plots":
    t = time.perf_counter(); session_page(r); page = time.perf_counter() - t
print(json.dumps({"wall": wall, "page": page, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "samples": r.samples}))
"""

COHORT = """
import json, sys
from hapticlab.sessions.review.cohort import review_folder
run = review_folder(sys.argv[1], workers=int(sys.argv[2]), progress=False)
print(json.dumps({"wall": run.wall_s, "workers": run.workers, "peaks": run.peak_rss_mb,
                  "reviewed": sum(o.value is not None for o in run.outcomes)}))
"""


def session(cache: Path, minutes: float, rate_hz: float = 1000.0) -> Path:
    """The demo for ``minutes`` with its sensor at ``rate_hz``, non-realtime, recorded once into ``cache``."""
    path = cache / f"demo-{minutes:g}min-{rate_hz:g}Hz.mcap"
    if not path.exists():
        print(f"making {path.name} ...", flush=True)
        subprocess.run(
            [
                sys.executable,
                "-c",
                "import sys; from hapticlab.sessions.cli import main; sys.exit(main())",
                "run",
                "demo",
                "--set",
                "session.realtime=false",
                "--set",
                f"session.duration={minutes * 60:g}",
                "--set",
                f"sensor.rate_hz={rate_hz:g}",
                "--set",
                "session.trainee=T01",
                "--set",
                "session.task=palpation",
                "--out",
                str(path),
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
    return path


def run(code: str, *args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=15.0, help="the long session, min (default 15)")
    parser.add_argument("--cohort", type=int, default=100, help="recordings in the cohort (default 100; 0: none)")
    parser.add_argument("--fast-minutes", type=float, default=3.0, help="the 7 kHz session, min (default 3)")
    parser.add_argument("--cache", default="/tmp/hapticlab-bench-review", help="where the sessions are kept")
    parser.add_argument("--cohort-only", action="store_true", help="measure the cohort only")
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    long = session(cache, args.minutes)
    short = session(cache, 1.0)
    fast = session(cache, args.fast_minutes, 7000.0)
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; {time.strftime('%Y-%m-%d %H:%M')}; "
        f"{long.name}: {long.stat().st_size / 1e6:.0f} MB",
        flush=True,
    )
    print(f"\nreview of a {args.minutes:g}-minute 1 kHz session (one process each; peak memory of the process)")
    for reader in () if args.cohort_only else ("fast", "reference"):
        for plots in ("noplots", "plots"):
            r = run(REVIEW, str(long), plots, reader)
            extra = f", then the HTML page with 4 plots {r['page']:.1f} s" if plots == "plots" else ""
            print(
                f"  {'chunks as columns' if reader == 'fast' else 'message at a time':18s} "
                f"{'with plots' if plots == 'plots' else 'no plots':10s} {r['wall']:7.1f} s, peak "
                f"{r['rss_mb']:.0f} MB ({r['samples']} samples){extra}",
                flush=True,
            )
    for path, what in (
        ()
        if args.cohort_only
        else ((short, "a 1-minute 1 kHz session"), (fast, f"a {args.fast_minutes:g}-minute 7 kHz session"))
    ):
        r1 = run(REVIEW, str(path), "plots", "fast")
        print(
            f"  memory: {what} ({r1['samples']} samples) peaks at {r1['rss_mb']:.0f} MB with plots "
            f"(review {r1['wall']:.2f} s)"
        )
    if args.cohort:
        folder = cache / f"cohort-{args.cohort}x{long.stem}"
        if not folder.exists():
            folder.mkdir()
            for i in range(args.cohort):
                os.link(long, folder / f"session-{i:03d}.mcap")
        print(
            f"\ncohort: {args.cohort} recordings of {args.minutes:g} min (hard links to {long.name}), "
            "review_folder (hapticlab review DIR/) on local workers"
        )
        walls = {}
        for workers in (1, 2):
            c = run(COHORT, str(folder), str(workers))
            walls[workers] = c["wall"]
            peaks = ", ".join(f"{v:.0f}" for v in c["peaks"].values())
            print(
                f"  {workers} worker(s): {c['wall']:.1f} s ({c['reviewed']} reviewed), peak memory per worker "
                f"{peaks} MB",
                flush=True,
            )
        print(f"  speed-up with 2 workers: {walls[1] / walls[2]:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
