"""How early can any estimator know the tool's weight from a real file's motion? (issue 16)

For each CSV file of a folder (default ``../shared/data/real``): gravity_force_B's std in units
of the noise σ after the first 10 %, 25 %, 50 % and all of the file, for a constant-bias
least-squares fit with σ known (``hapticlab.sessions.bench.identifiability``: the most the
motion can say), and the first row at which it falls below 0.5 σ (``kalman``'s automatic
convergence bound) and below 1 σ. No estimator can honestly converge earlier.

Run: ``.venv/bin/python bench/identifiability.py [FOLDER]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from hapticlab.sessions.bench.identifiability import first_below, gravity_std_over_rows
from hapticlab.sessions.recording.csvimport import read_csv


def main(folder: Path) -> None:
    print(
        f"{'file':24s} {'rows':>6s} | gravity std / σ after 10 %, 25 %, 50 %, 100 % of the rows "
        f"| first row < 0.5 σ, < 1 σ | a quarter"
    )
    for path in sorted(folder.glob("*.csv")):
        std = gravity_std_over_rows(read_csv(path).samples.R_EB)
        n = len(std)
        at = [std[max(int(n * f), 1) - 1] for f in (0.1, 0.25, 0.5, 1.0)]
        print(
            f"{path.stem:24s} {n:6d} | "
            + "  ".join(f"{v:8.3g}" for v in at)
            + f" | {first_below(std, 0.5)!s:>6}, {first_below(std, 1.0)!s:>6} | {n // 4}"
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
