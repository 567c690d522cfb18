"""The CSV import contract: raw wrench and robot orientation per row, read into a :class:`Stream`.

Header row, comma separated: ``t`` (s, increasing), ``fx,fy,fz`` (N) and
``tx,ty,tz`` (N·m) raw sensor wrench in S, ``qw,qx,qy,qz`` unit quaternion of
E in B (forward kinematics, i.e. R_BE), optional ``px,py,pz`` (m, E origin in
B), optional joint columns ``q1..q6`` (rad). Unknown extra columns are ignored
with a note. A missing or non-numeric required column, a non-unit quaternion
or a non-increasing ``t`` is a ``CsvError`` naming the file, line and column.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ...core.errors import UserError
from ...core.frames import matrix_from_quat_wxyz
from ...core.types import AlignedSamples

from .stream import Stream

REQUIRED = ("t", "fx", "fy", "fz", "tx", "ty", "tz", "qw", "qx", "qy", "qz")
POSITION = ("px", "py", "pz")
JOINTS = tuple(f"q{i}" for i in range(1, 7))
QUAT_TOLERANCE = 1e-3
"""Largest | ‖q‖ − 1 | accepted (then renormalised); printed quaternions carry ~1e-9."""


class CsvError(UserError, ValueError):
    """A CSV file breaks the import contract; the message names file, line and column."""


def read_csv(path: str | Path) -> Stream:
    """Import a CSV file that follows the contract as an offline stream.

    Every row is a sample: ``t_ns`` counts from the first row's ``t``, ``seq``
    is the row number, status good and nothing stale; R_EB is the transpose of
    the quaternion's R_BE. Joint columns, when present, ride along as ``joints``.
    """
    path = Path(path)
    name = path.name
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise CsvError(f"{name}: not a text CSV file") from None
    if not rows:
        raise CsvError(f"{name}: empty file; expected a header row with {','.join(REQUIRED)}")
    # blank lines (a trailing newline or two) are no rows; keep file line numbers for errors
    numbered = [(n, row) for n, row in enumerate(rows, start=1) if any(cell.strip() for cell in row)]
    if not numbered:
        raise CsvError(f"{name}: empty file; expected a header row with {','.join(REQUIRED)}")
    header = [h.strip() for h in numbered[0][1]]
    index = {h: i for i, h in enumerate(header)}
    missing = [c for c in REQUIRED if c not in index]
    if missing:
        raise CsvError(f"{name} line 1: missing required column(s) {', '.join(missing)} "
                       f"(required: {','.join(REQUIRED)})")
    lines = [n for n, _ in numbered[1:]]
    data = [row for _, row in numbered[1:]]
    if not data:
        raise CsvError(f"{name}: no data rows after the header")
    for n, row in zip(lines, data):
        if len(row) != len(header):
            raise CsvError(f"{name} line {n}: {len(row)} fields, the header has {len(header)}")

    has_position = all(c in index for c in POSITION)
    joint_cols = [c for c in JOINTS if c in index]
    known = set(REQUIRED) | (set(POSITION) if has_position else set()) | set(joint_cols)
    ignored = [h for h in header if h not in known]
    notes = [f"{name}: ignoring column(s) {', '.join(ignored)}"] if ignored else []

    def column(col: str) -> np.ndarray:
        values = [row[index[col]].strip() for row in data]
        try:
            out = np.array(values, dtype=float)
        except ValueError:
            out = None
        if out is not None and np.isfinite(out).all():
            return out
        for n, text in zip(lines, values):
            try:
                ok = np.isfinite(float(text))
            except ValueError:
                ok = False
            if not ok:
                raise CsvError(f"{name} line {n}, column {col!r}: {text!r} is not a finite number")
        raise AssertionError("unreachable")

    t = column("t")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if len(bad):
        n = lines[int(bad[0]) + 1]
        raise CsvError(f"{name} line {n}, column 't': {float(t[bad[0] + 1])!r} does not increase "
                       f"(previous {float(t[bad[0]])!r})")
    force_S = np.column_stack([column(c) for c in ("fx", "fy", "fz")])
    torque_S = np.column_stack([column(c) for c in ("tx", "ty", "tz")])
    quat = np.column_stack([column(c) for c in ("qw", "qx", "qy", "qz")])
    norm = np.linalg.norm(quat, axis=1)
    off = np.flatnonzero(np.abs(norm - 1.0) > QUAT_TOLERANCE)
    if len(off):
        k = int(off[0])
        raise CsvError(f"{name} line {lines[k]}, columns qw,qx,qy,qz: not a unit quaternion "
                       f"(norm {norm[k]:.6g})")
    quat = quat / norm[:, None]
    p = np.column_stack([column(c) for c in POSITION]) if has_position else None
    joints = np.column_stack([column(c) for c in joint_cols]) if joint_cols else None
    n = len(t)
    t_ns = np.round((t - t[0]) * 1e9).astype(np.int64)
    R_EB = matrix_from_quat_wxyz(quat).transpose(0, 2, 1)
    samples = AlignedSamples(t_ns, force_S, torque_S, R_EB, np.arange(n), np.zeros(n, dtype=np.int64),
                             np.zeros(n, dtype=bool), quat, p)
    return Stream(t, samples, notes, str(path), joints)


OUTPUT_COLUMNS = ("t", "fx", "fy", "fz", "tx", "ty", "tz", "contact", "converged_force", "converged_torque")


def write_compensated_csv(path: str | Path, t_s: np.ndarray, contact_force_S: np.ndarray,
                          contact_torque_S: np.ndarray, contact: np.ndarray,
                          converged_force: np.ndarray, converged_torque: np.ndarray) -> None:
    """Write the ``compensate`` output: the estimated contact wrench in S, one row per input row.

    Rows the estimator could not use (non-finite, stale or flagged by the
    sensor) carry NaN wrench values.
    """
    wrench = np.column_stack([contact_force_S, contact_torque_S])
    flags = np.column_stack([contact, converged_force, converged_torque]).astype(int)
    with Path(path).open("w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(OUTPUT_COLUMNS) + "\n")
        for t, values, f in zip(t_s.tolist(), wrench.tolist(), flags.tolist()):
            # t keeps full precision (epoch seconds need 16 digits); the wrench 9
            fh.write(f"{t!r}," + ",".join(f"{v:.9g}" for v in values) + f",{f[0]},{f[1]},{f[2]}\n")
