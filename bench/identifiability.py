"""How early can any estimator know the tool's weight from a real file's motion? (issue 16)

For each CSV file of a folder (default ``../shared/data/real``) this takes the most
information the motion can give about the force stage's parameters, x = [gravity_force_B,
bias_force_S]: a constant bias, a known noise σ and every row used (least squares over
rows 1..k, C_k = [R_EB, I3]), and prints the standard deviation of gravity_force_B in
units of σ after the first 10 %, 25 %, 50 % and all of the file, and the first row at
which it falls below 0.5 σ (``kalman``'s automatic convergence bound) and below 1 σ.

No estimator can honestly call gravity identified earlier than that row: with a
drifting bias, an unknown σ or rows refused as contact it can only be later.

Run: ``.venv/bin/python bench/identifiability.py [FOLDER]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from hapticlab.sessions.recording.csvimport import read_csv


def gravity_std_over_rows(R_EB: np.ndarray) -> np.ndarray:
    """(n,) largest std of gravity_force_B / σ after rows 1..k (inf while not determined)."""
    n = len(R_EB)
    C = np.concatenate([R_EB, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)  # (n, 3, 6)
    info = np.cumsum(np.einsum("kij,kil->kjl", C, C), axis=0)  # Σ CᵀC, (n, 6, 6)
    out = np.full(n, np.inf)
    for k in range(n):
        if np.linalg.cond(info[k]) < 1e12:
            out[k] = float(np.sqrt(np.linalg.inv(info[k]).diagonal()[:3].max()))
    return out


def first_below(std: np.ndarray, bound: float) -> int | None:
    below = np.flatnonzero(std < bound)
    return int(below[0]) if len(below) else None


def main(folder: Path) -> None:
    print(f"{'file':24s} {'rows':>6s} | gravity std / σ after 10 %, 25 %, 50 %, 100 % of the rows "
          f"| first row < 0.5 σ, < 1 σ | a quarter")
    for path in sorted(folder.glob("*.csv")):
        stream = read_csv(path)
        std = gravity_std_over_rows(stream.samples.R_EB)
        n = len(std)
        at = [std[max(int(n * f), 1) - 1] for f in (0.1, 0.25, 0.5, 1.0)]
        print(f"{path.stem:24s} {n:6d} | " + "  ".join(f"{v:8.3g}" for v in at)
              + f" | {first_below(std, 0.5)!s:>6}, {first_below(std, 1.0)!s:>6} | {n // 4}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real")
