"""Start-up time of the ``hapticlab`` command, against a bare interpreter in the same run.

    .venv/bin/python bench/startup.py [--runs 15] [--session]

Starts each command in a fresh interpreter ``--runs`` times, in turn with ``python -c pass`` (A B A B ...,
so a change in the machine's load falls on both), and prints per command the median, min and max of the
wall time (start to exit) and of the CPU time (user + system, the operating system's count for the child),
and the median of the paired ratio to the bare interpreter. The commands: ``--version``, ``plugins``,
``--help`` and ``run --help``; with ``--session`` also a whole 1 s simulated session, not paced
(``run --duration 1 --set session.realtime=false``, its recording in a temporary folder), which pays for
numba's cached kernels, the plugins it builds and the recording's writer. The hapticlab measured is the
one this interpreter imports (its path is printed first). Numbers vary with the machine and its load:
quote them, never assert them.
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLI = "from hapticlab.sessions.cli import main; raise SystemExit(main())"
"""What the installed ``hapticlab`` script runs."""

COMMANDS = (["--version"], ["plugins"], ["--help"], ["run", "--help"])
OUT = "{out}"
"""Stands for the session's recording: a new file in a temporary folder each run."""


def timed(args: list[str]) -> tuple[float, float]:
    """(wall s, cpu s) of one run of ``args`` to its end; its output is discarded, a failure raises."""
    before = os.times()
    start = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = os.times()
    return wall, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def spread(values: list[float]) -> str:
    return f"{statistics.median(values):8.3f} {min(values):7.3f} {max(values):7.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15, help="runs of each command (default 15), after one warm-up")
    parser.add_argument("--session", action="store_true", help="also a whole 1 s simulated session, not paced")
    options = parser.parse_args()
    import hapticlab

    print(f"hapticlab from {Path(hapticlab.__file__).parent}; {options.runs} runs each, in turn with python -c pass")
    bare = [sys.executable, "-c", "pass"]
    with tempfile.TemporaryDirectory() as folder:
        commands = [[*c] for c in COMMANDS]
        if options.session:
            commands.append(["run", "--duration", "1", "--set", "session.realtime=false", "--out", OUT])
        print(
            f"{'command':<34}{'wall s: median':>15} {'min':>7} {'max':>7}{'cpu s: median':>15} {'min':>7} {'max':>7}"
            f"{'wall / bare':>12}"
        )
        base_wall: list[float] = []
        base_cpu: list[float] = []
        runs = itertools.count()

        def args(command: list[str]) -> list[str]:  # a new recording each run (run refuses to overwrite one)
            out = str(Path(folder) / f"session-{next(runs)}.mcap")
            return [sys.executable, "-c", CLI, *(out if word == OUT else word for word in command)]

        for command in commands:
            timed(args(command))  # warm-up: the file cache, numba's cache on disk
            timed(bare)
            walls, cpus, ratios = [], [], []
            for _ in range(options.runs):
                wall, cpu = timed(args(command))
                wall_bare, cpu_bare = timed(bare)
                walls.append(wall)
                cpus.append(cpu)
                ratios.append(wall / wall_bare)
                base_wall.append(wall_bare)
                base_cpu.append(cpu_bare)
            label = "hapticlab run, a 1 s session" if OUT in command else "hapticlab " + " ".join(command)
            print(f"{label:<34}{spread(walls):>31}{spread(cpus):>31}{statistics.median(ratios):>12.1f}")
        print(f"{'python -c pass':<34}{spread(base_wall):>31}{spread(base_cpu):>31}{1.0:>12.1f}")


if __name__ == "__main__":
    main()
