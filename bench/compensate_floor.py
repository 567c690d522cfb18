"""``compensate`` against the numpy floor on a large simulated CSV: how far from library speed is it?

    .venv/bin/python bench/compensate_floor.py [--rows N] [--estimators rls,kalman,batch] [--keep DIR]
    .venv/bin/python bench/compensate_floor.py make FILE [--rows N]      # the input file only
    .venv/bin/python bench/compensate_floor.py floor FILE OUT.csv        # the floor alone (for an outside timer)

The input is a seeded simulated recording (``SimWorld(seed=1)``, 1 kHz, a 0.35 kg
tool on a random tour; default 1e6 rows) written as the CSV import contract with
9 significant digits, as a logger would. The floor is what plain numpy does with
the same job: ``np.loadtxt``, one vectorised least-squares fit of the paper's model
over every row (force, then torque), the contact wrench as its residual, and
``np.savetxt`` of the ten output columns. ``compensate`` runs with each estimator
over the same file in the same run, each in a fresh interpreter (start-up
included, as a user sees it); the table gives wall seconds, rows/s, the ratio to
the floor and each process's peak resident memory.
Numbers vary with the machine and its load: quote them, never assert them.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HEADER = "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz"
OUTPUT = "t,fx,fy,fz,tx,ty,tz,contact,converged_force,converged_torque"


def make(path: Path, rows: int) -> None:
    """Write ``rows`` simulated samples (seeded) at 1 kHz as a contract CSV, in slices (memory stays small)."""
    from hapticlab.core.frames import quat_wxyz_from_matrix
    from hapticlab.plugins.simworld import SimWorld
    from hapticlab.sessions.bench.simulation import simulate

    world = SimWorld(seed=1, inertia=False)
    step = 100_000
    with path.open("w") as fh:
        fh.write(HEADER + "\n")
        for start in range(0, rows, step):
            n = min(step, rows - start)
            block, _ = simulate(world, n / 1000.0, 1000.0, t0=start / 1000.0)
            quat_BE = quat_wxyz_from_matrix(block.R_EB.transpose(0, 2, 1))
            t = (start + np.arange(n)) / 1000.0
            np.savetxt(fh, np.column_stack([t, block.force_S, block.torque_S, quat_BE]), fmt="%.9g", delimiter=",")


def skew_rows(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) skew matrices of (N, 3) vectors."""
    z = np.zeros(len(v))
    return np.stack(
        [np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1), np.stack([-v[:, 1], v[:, 0], z], 1)],
        1,
    )


def floor(path: Path, out: Path) -> None:
    """The numpy floor: read, one batch least-squares fit over every row, write the ten output columns."""
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    t, force_S, torque_S, q = data[:, 0], data[:, 1:4], data[:, 4:7], data[:, 7:11]
    q = q / np.linalg.norm(q, axis=1)[:, None]
    w, x, y, z = q.T
    R_BE = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1),
        ],
        1,
    )
    R_EB = R_BE.transpose(0, 2, 1)
    n = len(t)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    A = np.concatenate([R_EB, eye], axis=2).reshape(3 * n, 6)  # S_f = R_EB B_f + f0
    x_f = np.linalg.lstsq(A, force_S.reshape(-1), rcond=None)[0]
    contact_force = force_S - (A @ x_f).reshape(n, 3)
    f_rel = force_S - x_f[3:]
    A = np.concatenate([-skew_rows(f_rel), eye], axis=2).reshape(3 * n, 6)  # S_tau = -skew(S_f - f0) p + tau0
    x_t = np.linalg.lstsq(A, torque_S.reshape(-1), rcond=None)[0]
    contact_torque = torque_S - (A @ x_t).reshape(n, 3)
    flags = np.column_stack([np.zeros(n), np.ones(n), np.ones(n)])
    table = np.column_stack([t, contact_force, contact_torque, flags])
    np.savetxt(out, table, fmt=["%.17g"] + ["%.9g"] * 6 + ["%d"] * 3, delimiter=",", header=OUTPUT, comments="")


def timed(argv: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident memory (MiB) of a command run to its end (its output thrown away)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    dt = time.perf_counter() - t0
    if status:
        raise SystemExit(f"{' '.join(argv)}: exit status {status}")
    return dt, usage.ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", choices=("make", "floor"), help="one step alone (default: the whole table)")
    parser.add_argument("paths", nargs="*", type=Path)
    parser.add_argument("--rows", type=float, default=1e6)
    parser.add_argument("--estimators", default="rls,kalman,batch")
    parser.add_argument("--keep", type=Path, help="a folder for the files (default: a temporary one)")
    args = parser.parse_args()
    rows = int(args.rows)
    if args.what == "make":
        return make(args.paths[0], rows)
    if args.what == "floor":
        return floor(args.paths[0], args.paths[1])
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        src = folder / f"sim_{rows}.csv"
        if not src.exists():
            make(src, rows)
        cli = "from hapticlab.sessions.cli import main; main()"
        runs = {"numpy floor": [sys.executable, __file__, "floor", str(src), str(folder / "floor.csv")]}
        for name in args.estimators.split(","):
            out = str(folder / f"{name}.csv")
            runs[f"compensate {name}"] = [sys.executable, "-c", cli, "compensate", str(src), "-o", out]
            runs[f"compensate {name}"] += ["--estimator", name, "--force"]
        print(f"{rows:,} rows ({src.stat().st_size / 2**20:.0f} MiB CSV), each a fresh process")
        print(f"{'':22}{'wall s':>8}{'rows/s':>11}{'x floor':>9}{'peak MiB':>10}")
        base = None
        for label, argv in runs.items():
            dt, peak = timed(argv)
            base = base or dt
            print(f"{label:22}{dt:8.2f}{rows / dt:11,.0f}{dt / base:9.2f}{peak:10.0f}")


if __name__ == "__main__":
    main()
