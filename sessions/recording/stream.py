"""The one offline stream type: every offline tool (compensate, replay, bench real, discrepancy) takes a ``Stream``.

A stream is a recording's rows as :class:`~hapticlab.core.types.AlignedSamples`
(each wrench sample paired with the orientation at its own time) plus what the
file said beside them: the time in s, notes for the user, the file it came
from and, from a CSV with joint columns, the joint positions. The readers that
build one, :mod:`.csvimport` (the CSV import contract) and :mod:`.mcapimport`
(a session recording), import this module; :func:`~.loader.load_stream` picks
one by the file's suffix.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.types import AlignedSamples

CHUNK_ROWS = 16384
"""Rows per chunk when a file is streamed (``compensate``): memory is a small multiple of this, not of the file."""


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

    @classmethod
    def concatenate(cls, parts: list[Stream]) -> Stream:
        """Consecutive chunks of one file (:func:`~.loader.iter_stream`) as one stream; the notes of every chunk."""
        if len(parts) == 1:
            return parts[0]
        joints = [p.joints for p in parts if p.joints is not None]
        return cls(
            np.concatenate([p.t_s for p in parts]),
            concat_samples([p.samples for p in parts]),
            [note for p in parts for note in p.notes],
            parts[0].source,
            np.concatenate(joints) if len(joints) == len(parts) else None,
        )

    @property
    def name(self) -> str:
        """The file name (for messages), or "stream" when built in memory."""
        return Path(self.source).name if self.source else "stream"


def unused_note(name: str, unused: int) -> list[str]:
    """The note on samples no estimator may see (none for a CSV file, whose rows are checked on import)."""
    return [f"{name}: {unused} sample(s) not used (stale orientation, sensor status or non-finite)"] if unused else []


def concat_samples(parts: list[AlignedSamples]) -> AlignedSamples:
    """Consecutive blocks of aligned samples as one (the one block itself when there is one)."""
    if len(parts) == 1:
        return parts[0]
    arrays: dict[str, Any] = {}  # the required fields are arrays in every part; the optional ones may be None
    for f in fields(AlignedSamples):
        values = [getattr(p, f.name) for p in parts]
        arrays[f.name] = None if any(v is None for v in values) else np.concatenate(values)
    return AlignedSamples(**arrays)


QUAT_TOLERANCE = 1e-3
"""Largest | ‖q‖ − 1 | accepted (then renormalised); printed quaternions carry ~1e-9."""


def off_unit(norm: np.ndarray) -> int | None:
    """The first row whose quaternion norm is off 1 by more than :data:`QUAT_TOLERANCE` (NaN passes), or None."""
    off = np.flatnonzero(np.abs(norm - 1.0) > QUAT_TOLERANCE)
    return int(off[0]) if len(off) else None
