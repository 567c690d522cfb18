"""How long a review takes, and how much memory: one long session, and a cohort with one and two workers.

    .venv/bin/python bench/review.py [--minutes 15] [--cohort 100] [--cohort-minutes 1] [--cache DIR]

Sessions are the demo (1 kHz, ``rls``, recording on) run non-realtime for the
given length, once, into ``--cache`` (kept between runs: a 15-minute one takes
~7 minutes to make here). Each measurement runs in a fresh Python process so
its peak memory (``ru_maxrss``) is its own:

* one session: ``review`` read a chunk at a time as columns (the default) and
  a message at a time (the reference reader, every format), without plots and
  with them (the haptic commands read, the envelopes filled), then the HTML
  page and the four PNGs drawn;
* memory: the same review of a 1-minute and of the long session (flat: the
  pass holds a few chunks of samples, never the file);
* a cohort: ``--cohort`` recordings in a folder, copies of ``--cohort-minutes``
  sessions of five trainees (the review's work per file does not depend on
  what is in it), through ``hapticlab review DIR/`` with one and with two
  local workers: wall time (the Dask cluster's start included), speed-up, and
  each worker's peak memory.

Numbers vary with the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

REVIEW = """
import json, resource, sys, time
from hapticlab.sessions.review import review
from hapticlab.sessions.review.page import session_page
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


def session(cache: Path, minutes: float, trainee: str = "T01", seed: int = 7) -> Path:
    """The demo for ``minutes``, non-realtime, recorded once into ``cache``."""
    path = cache / f"demo-{minutes:g}min-{trainee}.mcap"
    if not path.exists():
        print(f"making {path.name} ...", flush=True)
        subprocess.run([sys.executable, "-m", "hapticlab.sessions.cli", "run", "demo", "--set", "session.realtime=false",
                        "--set", f"session.duration={minutes * 60:g}", "--set", f"session.trainee={trainee}",
                        "--set", "session.task=palpation", "--set", f"world.seed={seed}", "--out", str(path)],
                       check=True, stdout=subprocess.DEVNULL)
    return path


def run(code: str, *args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", code, *args], check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=15.0, help="the long session, min (default 15)")
    parser.add_argument("--cohort", type=int, default=100, help="recordings in the cohort (default 100; 0: none)")
    parser.add_argument("--cohort-minutes", type=float, default=1.0, help="each cohort session, min (default 1)")
    parser.add_argument("--cache", default="/tmp/hapticlab-bench-review", help="where the sessions are kept")
    args = parser.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    long = session(cache, args.minutes)
    short = session(cache, 1.0)
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; {time.strftime('%Y-%m-%d %H:%M')}; "
          f"{long.name}: {long.stat().st_size / 1e6:.0f} MB", flush=True)
    print(f"\nreview of a {args.minutes:g}-minute 1 kHz session (one process each; peak memory of the process)")
    for reader in ("fast", "reference"):
        for plots in ("noplots", "plots"):
            r = run(REVIEW, str(long), plots, reader)
            extra = f", then the HTML page with 4 plots {r['page']:.1f} s" if plots == "plots" else ""
            print(f"  {'chunks as columns' if reader == 'fast' else 'message at a time':18s} "
                  f"{'with plots' if plots == 'plots' else 'no plots':10s} {r['wall']:7.1f} s, peak "
                  f"{r['rss_mb']:.0f} MB ({r['samples']} samples){extra}", flush=True)
    r1 = run(REVIEW, str(short), "plots", "fast")
    print(f"  memory: a 1-minute session peaks at {r1['rss_mb']:.0f} MB with plots (review {r1['wall']:.2f} s)")
    if args.cohort:
        folder = cache / f"cohort-{args.cohort}x{args.cohort_minutes:g}min"
        if not folder.exists():
            sources = [session(cache, args.cohort_minutes, f"T{k:02d}", seed=k + 3) for k in range(1, 6)]
            folder.mkdir()
            for i in range(args.cohort):
                shutil.copy(sources[i % 5], folder / f"session-{i:03d}.mcap")
        size = sum(p.stat().st_size for p in folder.glob("*.mcap")) / 1e6
        print(f"\ncohort: {args.cohort} recordings of {args.cohort_minutes:g} min ({size:.0f} MB), "
              "hapticlab review DIR/ on local workers")
        walls = {}
        for workers in (1, 2):
            c = run(COHORT, str(folder), str(workers))
            walls[workers] = c["wall"]
            peaks = ", ".join(f"{v:.0f}" for v in c["peaks"].values())
            print(f"  {workers} worker(s): {c['wall']:.1f} s ({c['reviewed']} reviewed), peak memory per worker "
                  f"{peaks} MB", flush=True)
        print(f"  speed-up with 2 workers: {walls[1] / walls[2]:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
