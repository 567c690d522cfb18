"""How the defaults hold up under a trainee's touches: random indentations, from light to heavy work (issue 16).

Simulated at 1 kHz on a random tour turning ~19°/s (0.12 N, 0.01 N·m of noise, the paper's tool, seed 2025),
180 s; the touches begin at 15 s (after the identification a teleoperation's calibration tour gives). Each
touch has a random peak force, duration, ramp (rise and fall time) and direction (fixed in B, the tissue's
frame: random, or straight up, which is what a lighter tool looks like). For each workload, ``kalman`` with
its defaults and with the noise given: the payload changes it named (every one false here), where both flags
are up the RMS error of the contact force per axis in contact and out of it (N), the share of samples whose
contact force is more than 1 N off with both flags up, and the share of the touching samples judged a
contact. The table in docs/estimators.md ("Payload change") is this script's output.

Run: ``.venv/bin/python bench/random_touches.py`` (about 10 s).
"""

from __future__ import annotations

import numpy as np

from hapticlab.plugins.estimators.kalman import IDENTIFICATION_EVENTS, KalmanEstimator
from hapticlab.sessions.bench.paper_setup import PaperSetup
from hapticlab.sessions.bench.simulation import feed, simulate

SECONDS = 180.0
FIRST_TOUCH_S = 15.0
TOUR = {"script": "random_tour", "max_tilt_deg": 60.0, "segment_s": 3.0}
NOISE = {"noise_force": 0.12, "noise_torque": 0.01}
WORKLOADS = (
    # label, peak force (N), duration (s), ramp (s), mean gap between touches (s), straight up in B
    ("0.3–1.2 N, any direction, gaps of 3 s", (0.3, 1.2), (0.5, 3.0), (0.1, 0.5), 3.0, False),
    ("0.5–4 N, any direction, gaps of 2 s", (0.5, 4.0), (0.5, 5.0), (0.05, 0.6), 2.0, False),
    ("0.5–4 N, straight up, gaps of 5 s", (0.5, 4.0), (0.5, 5.0), (0.05, 0.6), 5.0, True),
    ("0.5–4 N, straight up, gaps of 3 s", (0.5, 4.0), (0.5, 5.0), (0.05, 0.6), 3.0, True),
    ("0.5–4 N, straight up, gaps of 1 s", (0.5, 4.0), (0.5, 5.0), (0.05, 0.6), 1.0, True),
    ("2–6 N held 5–20 s, any direction, gaps of 3 s", (2.0, 6.0), (5.0, 20.0), (0.2, 0.8), 3.0, False),
)


def touches(rng: np.random.Generator, peak, duration, ramp, gap: float, up: bool) -> list[dict]:
    """Indentations from FIRST_TOUCH_S to 3 s before the end, one after another with exponential gaps."""
    out, t = [], FIRST_TOUCH_S
    while t < SECONDS - 3.0:
        d = np.array([0.0, 0.0, 1.0]) if up else rng.normal(size=3)
        length = rng.uniform(*duration)
        out.append(
            {
                "kind": "indentation",
                "start": t,
                "duration": length,
                "peak_force": rng.uniform(*peak),
                "ramp": min(rng.uniform(*ramp), length / 2),
                "direction_B": list(d / np.linalg.norm(d)),
            }
        )
        t += length + rng.exponential(gap)
    return out


def axes(v) -> str:
    return " / ".join(f"{x:.2f}" for x in v)


def main() -> None:
    print("| touches | noise | duty | payload changes | in contact | free | > 1 N off | judged a contact |")
    print("|---" * 8 + "|")
    for k, (label, peak, duration, ramp, gap, up) in enumerate(WORKLOADS):
        contacts = touches(np.random.default_rng(100 + k), peak, duration, ramp, gap, up)
        world = PaperSetup(seed=2025).world(TOUR, contacts, **NOISE)
        block, truth = simulate(world, SECONDS, 1000.0)
        touching = np.asarray(truth["contact"], dtype=bool)
        for noise, options in (("estimated", {}), ("given", NOISE)):
            est = KalmanEstimator(**options)
            out, _ = feed(est, block, chunk=64)
            up_both = out.converged_force & out.converged_torque
            error = out.contact_force_S - truth["contact_force_S"]
            inside = np.sqrt(np.mean(error[touching & up_both] ** 2, axis=0))
            outside = np.sqrt(np.mean(error[~touching & up_both] ** 2, axis=0))
            far = np.mean((np.linalg.norm(error, axis=1) > 1.0) & up_both)
            changes = sum(e.kind == "payload_change" for e in est.events if e.kind not in IDENTIFICATION_EVENTS)
            print(
                f"| {label} ({len(contacts)}) | {noise} | {touching.mean():.0%} | {changes} | {axes(inside)} | "
                f"{axes(outside)} | {far:.1%} | {out.contact[touching].mean():.0%} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
