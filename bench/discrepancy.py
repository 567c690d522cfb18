"""Speed of ``hapticlab discrepancy`` on a 2-minute 500 Hz recording (60 000 samples).

    .venv/bin/python bench/discrepancy.py [--duration 120] [--rate 500] [--case three|five|both]

Two recordings, each with four tip indentations for the contact gate:

* ``three``: three hidden effects (a 2.7° mount rotation, an 8 ms kinematics
  lag and the tool's inertia on a lively tour with flange translations);
* ``five``: the worst case, every built-in effect hidden (those three, plus
  0.5 N/min of force drift and a 1–2 % force calibration error), so five
  rounds of candidates and five re-identifications.

Each is written as a CSV, then the whole command is timed
(``hapticlab discrepancy FILE --json --plots`` in a fresh process: start-up,
reading the CSV, the workflow, plots, JSON) and the workflow alone in this
process. Prints what it named. Numbers vary with the machine and its load:
quote them, never assert them.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hapticlab.plugins.simworld import Indentation, RandomTour, RobotParams, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.sessions.discrepancy.workflow import discrepancy

COMMAND = "import sys; from hapticlab.sessions.cli import main; sys.exit(main(sys.argv[1:]))"
"""``hapticlab`` in a fresh process (``sessions.cli`` is a package without ``__main__``)."""

GF = np.array([[0.02, 0.01, -0.005], [0.01, -0.015, 0.008], [-0.005, 0.008, -0.005]])


def world_for(case: str) -> tuple[SimWorld, str]:
    sensor = {"mount_rotation_SE": np.deg2rad([2.0, -1.5, 1.0])}
    hidden = "mount_rotation, time_lag, inertia"
    if case == "five":
        sensor |= {"drift_force_S": np.array([0.5, -0.3, 0.4]) / 60, "gain_force_S": GF}
        hidden += ", bias_drift, gain_crosstalk"
    world = SimWorld(
        sensor=SensorParams(**sensor),
        robot=RobotParams(kinematics_lag_s=0.008),
        motion=RandomTour(seed=3, segment_s=1.0, max_translation=0.05),
        contacts=[Indentation(start=s, duration=1.5, peak_force=2.5) for s in (20.0, 50.0, 80.0, 100.0)],
        seed=3,
        inertia=True,
    )
    return world, hidden


def bench(case: str, duration: float, rate: float) -> None:
    world, hidden = world_for(case)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.csv"
        write_csv(world, path, duration, rate)
        n = sum(1 for _ in path.open()) - 1
        print(f"[{case}] {n} samples ({duration:g} s at {rate:g} Hz), hidden: {hidden}; 4 indentations")
        start = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-c",
                COMMAND,
                "discrepancy",
                str(path),
                "--json",
                str(Path(tmp) / "out.json"),
                "--plots",
                str(Path(tmp) / "plots"),
            ],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        command = time.perf_counter() - start
        start = time.perf_counter()
        result = discrepancy(path)
        workflow = time.perf_counter() - start
    print(f"  named {result['effects']}; gated {result['gated']} samples; fitted on {result['fit_samples']}")
    print(
        f"  final force RMS {np.round(result['final']['rms_force_S'], 4).tolist()} N "
        f"(noise {world.sensor.noise_force_S[0]:g} N)"
    )
    print(f"  whole command (fresh process, CSV read, plots, JSON): {command:.1f} s")
    print(f"  workflow alone (CSV read included): {workflow:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=120.0, help="s (default 120)")
    parser.add_argument("--rate", type=float, default=500.0, help="samples/s (default 500)")
    parser.add_argument(
        "--case",
        default="both",
        choices=("three", "five", "both"),
        help="three hidden effects, all five, or both (default)",
    )
    args = parser.parse_args()
    for case in ("three", "five") if args.case == "both" else (args.case,):
        bench(case, args.duration, args.rate)


if __name__ == "__main__":
    main()
