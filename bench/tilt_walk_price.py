"""What the tilt walk costs where the gate cannot see a contact, and what its span takes away (issue 16).

Simulated at 1 kHz on a random tour turning ~19°/s (0.12 N of noise, seed 2025): 3 N indentations with the
model exact and with a 5° mount it lacks, and light touches under the gate. For each, the in-contact error of
the contact force per axis (N) with the walk off, learnt without a span (``bias_tilt_span = 0``) and learnt
with the default span, and the walk learnt (N/√rad). The table in docs/estimators.md ("The tilt walk") is
this script's output.

Run: ``.venv/bin/python bench/tilt_walk_price.py`` (about two minutes).
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.plugins.estimators.kalman import KalmanEstimator
from hapticlab.sessions.bench.family import MOUNT_ROTATION_SE
from hapticlab.sessions.bench.paper_setup import PaperSetup
from hapticlab.sessions.bench.simulation import feed, simulate

VARIANTS = (
    ("walk off", {"bias_force_tilt_rw": 0.0}),
    ('"auto", no span', {"bias_force_tilt_rw": "auto", "bias_tilt_span": 0.0}),
    ('"auto" (span 0.15 rad)', {"bias_force_tilt_rw": "auto"}),
)


def presses(start: float, every: float, seconds: float, peak: float) -> list[dict]:
    """Indentations of 2 s (0.4 s ramps) from ``start`` every ``every`` s until ``seconds``, peak force in N."""
    return [
        {"kind": "indentation", "start": start + every * k, "duration": 2.0, "peak_force": peak, "ramp": 0.4}
        for k in range(math.ceil((seconds - start) / every))
    ]


def row(label: str, contacts: list[dict], seconds: float, **sensor) -> str:
    world = PaperSetup(seed=2025).world(
        {"script": "random_tour", "max_tilt_deg": 60.0, "segment_s": 3.0},
        contacts,
        noise_force=0.12,
        noise_torque=0.01,
        **sensor,
    )
    block, truth = simulate(world, seconds, 1000.0)
    touching = np.asarray(truth["contact"], dtype=bool)
    cells = [label]
    for _, options in VARIANTS:
        est = KalmanEstimator(**options)
        out, _ = feed(est, block, chunk=64)
        error = np.sqrt(np.mean((out.contact_force_S - truth["contact_force_S"])[touching] ** 2, axis=0))
        learnt = est.params().get("bias_force_tilt_rw")
        cells.append(" / ".join(f"{v:.2f}" for v in error) + ("" if learnt is None else f" ({learnt[0]:.3f})"))
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    print("| scenario | " + " | ".join(label for label, _ in VARIANTS) + " |")
    print("|---" * (len(VARIANTS) + 1) + "|")
    indentations = presses(5.0, 10.0, 180.0, 3.0)
    print(row("3 N indentations every 10 s, 180 s, the model exact", indentations, 180.0), flush=True)
    print(
        row("the same with a 5° mount the model lacks", indentations, 180.0, mount_rotation=MOUNT_ROTATION_SE),
        flush=True,
    )
    for every, peak in ((4.0, 0.5), (4.0, 0.8), (10.0, 0.5)):
        print(row(f"{peak} N touches, 2 s in every {every:g}, 60 s", presses(1.0, every, 60.0, peak), 60.0), flush=True)


if __name__ == "__main__":
    main()
