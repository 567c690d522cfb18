"""How ``hapticlab discrepancy`` scales with the recording's length, against a numpy floor on the same file.

    .venv/bin/python bench/discrepancy_scale.py write --rows 600000 OUT.csv   # the seeded recording
    .venv/bin/python bench/discrepancy_scale.py floor OUT.csv                 # the numpy floor, one run
    .venv/bin/python bench/discrepancy_scale.py split OUT.csv                 # read and workflow, timed apart

``write``: the ``three`` world of ``bench/discrepancy.py`` (a 2.7° mount
rotation, an 8 ms kinematics lag, the tool's inertia on a lively tour with
flange translations, four tip indentations; seed 3) at 500 Hz for
``rows / 500`` s, as a CSV of the import contract. ``floor``: what any
offline analysis of that file costs at least: ``np.loadtxt``, the paper's
batch least-squares fit vectorised over the rows (force, then torque) and
``np.savetxt`` of the residual. ``split``: the CSV read and the workflow
(``discrepancy`` on the stream read) timed apart in one process, with the
peak RSS of each: the reader is another module's, the workflow must not
depend on it. Time the whole command from outside (``/usr/bin/time -v``,
paired runs); numbers vary with the machine and its load: quote them, never
assert them.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def write(rows: int, out: Path) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from discrepancy import world_for

    from hapticlab.plugins.simworld.export import write_csv

    world, hidden = world_for("three")
    write_csv(world, out, rows / 500.0, 500.0)
    print(f"{out}: {rows} rows at 500 Hz, hidden: {hidden}; 4 indentations")


def floor(path: Path) -> None:
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    force_S, torque_S, q = data[:, 1:4], data[:, 4:7], data[:, 7:11]
    w, x, y, z = q.T
    R_BE = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )
    R_EB = R_BE.transpose(0, 2, 1)
    n, eye = len(data), np.broadcast_to(np.eye(3), (len(data), 3, 3))
    x_f = np.linalg.lstsq(np.concatenate([R_EB, eye], 2).reshape(3 * n, 6), force_S.reshape(-1), rcond=None)[0]
    fx, fy, fz = force_S.T
    zero = np.zeros(n)
    A = -np.stack([np.stack([zero, -fz, fy], -1), np.stack([fz, zero, -fx], -1), np.stack([-fy, fx, zero], -1)], 1)
    x_t = np.linalg.lstsq(np.concatenate([A, eye], 2).reshape(3 * n, 6), torque_S.reshape(-1), rcond=None)[0]
    gravity_S = R_EB @ x_f[:3]
    residual = np.concatenate([force_S - gravity_S - x_f[3:], torque_S - np.cross(x_t[:3], force_S) - x_t[3:]], axis=1)
    with tempfile.TemporaryDirectory() as tmp:
        np.savetxt(Path(tmp) / "residual.csv", residual, delimiter=",", fmt="%.10g")
    print(f"{n} rows; weight {np.linalg.norm(x_f[:3]):.4f} N")


def split(path: Path) -> None:
    from hapticlab.sessions.discrepancy.workflow import discrepancy
    from hapticlab.sessions.recording.loader import load_stream

    start = time.perf_counter()
    stream = load_stream(path)
    read = time.perf_counter() - start
    peak_read = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    start = time.perf_counter()
    result = discrepancy(stream)
    workflow = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"{result['samples']} rows: read {read:.2f} s (peak {peak_read:.0f} MB), workflow {workflow:.2f} s "
        f"(peak {peak:.0f} MB); named {result['effects']}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("write", help="write the seeded recording")
    p.add_argument("--rows", type=int, default=600000, help="rows at 500 Hz (default 600000)")
    p.add_argument("out", type=Path)
    sub.add_parser("floor", help="the numpy floor on a file").add_argument("path", type=Path)
    sub.add_parser("split", help="the read and the workflow timed apart").add_argument("path", type=Path)
    args = parser.parse_args()
    if args.what == "write":
        write(args.rows, args.out)
    elif args.what == "floor":
        floor(args.path)
    else:
        split(args.path)


if __name__ == "__main__":
    main()
