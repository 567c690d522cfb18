"""The one offline stream type: every offline tool (compensate, replay, bench real, discrepancy) takes a ``Stream``.

A stream is a recording's rows as :class:`~hapticlab.core.types.AlignedSamples`
(each wrench sample paired with the orientation at its own time) plus what the
file said beside them: the time in s, notes for the user, the file it came
from and, from a CSV with joint columns, the joint positions.
:func:`load_stream` reads a CSV (the import contract, ``csvimport``) or an MCAP
session recording (poses interpolated at every wrench sample) into one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.aligner import orientation_at, position_at
from ...core.frames import matrix_from_quat_wxyz
from ...core.types import AlignedSamples


@dataclass
class Stream:
    """A recording's rows, ready for any offline tool.

    Attributes:
        t_s: (N,) time of each row, s (a CSV's own ``t``; from 0 for an MCAP file).
        samples: the rows as aligned samples (``t_ns``: an MCAP file's log time; a CSV's ``t`` from 0, in ns).
        notes: what the reader wants the user to know (ignored columns, unusable rows).
        source: the file it came from ("" when built in memory).
        joints: (N, k) joint positions, rad, when the file has them (CSV ``q1..q6``), else None.
    """

    t_s: np.ndarray
    samples: AlignedSamples
    notes: list[str] = field(default_factory=list)
    source: str = ""
    joints: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def name(self) -> str:
        """The file name (for messages), or "stream" when built in memory."""
        return Path(self.source).name if self.source else "stream"


def load_stream(path: str | Path) -> Stream:
    """Read a CSV (import contract) or an MCAP recording (``.mcap``) into a stream."""
    # csvimport builds its Stream from this module: import it here, not at the top
    from .csvimport import CsvError, read_csv

    path = Path(path)
    if not path.exists():
        raise CsvError(f"{path}: no such file")
    if path.suffix.lower() == ".mcap":
        return _load_mcap(path)
    return read_csv(path)


def _load_mcap(path: Path) -> Stream:
    from .csvimport import CsvError
    from .reader import read_recording

    recording = read_recording(path)
    wrenches = recording.topics.get("/sensor/wrench", [])
    poses = recording.topics.get("/kinematics/pose", [])
    if not wrenches:
        raise CsvError(f"{path.name}: no /sensor/wrench messages")
    if not poses:
        raise CsvError(f"{path.name}: no /kinematics/pose messages")
    t_ns = np.array([t for t, _ in wrenches], dtype=np.int64)
    # NaN is recorded as null in JSON; float(None) would fail, so map it back
    force_S = np.array([[np.nan if v is None else v for v in m["force_S"]] for _, m in wrenches], dtype=float)
    torque_S = np.array([[np.nan if v is None else v for v in m["torque_S"]] for _, m in wrenches], dtype=float)
    status = np.array([int(m.get("status", 0)) for _, m in wrenches], dtype=np.int64)
    pose_t = np.array([t for t, _ in poses], dtype=np.int64)
    quat = np.array([m["quat_BE"] for _, m in poses], dtype=float)
    period = int(np.median(np.diff(pose_t))) if len(pose_t) > 1 else 0
    quat_BE, stale = orientation_at(t_ns, pose_t, quat, period)
    R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
    p_BoEo_B = None
    if all(m.get("p_BoEo_B") is not None for _, m in poses):
        p_BoEo_B = position_at(t_ns, pose_t, np.array([m["p_BoEo_B"] for _, m in poses], dtype=float), period)
    seq = np.array([int(m.get("seq", k)) for k, (_, m) in enumerate(wrenches)], dtype=np.int64)
    samples = AlignedSamples(t_ns, force_S, torque_S, R_EB, seq, status, stale, quat_BE, p_BoEo_B)
    unused = int(np.count_nonzero(~samples.usable))
    notes = [f"{path.name}: {unused} sample(s) not used (stale orientation, sensor status or non-finite)"] \
        if unused else []
    return Stream((t_ns - t_ns[0]) * 1e-9, samples, notes, str(path))
