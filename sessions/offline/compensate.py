"""Offline compensation: run an estimator over a CSV, Parquet or MCAP recording; the output CSV or Parquet.

The estimator sees the rows in order, in blocks, exactly as it would live; the
output has one row per input row (the estimated contact wrench in S and the
contact and convergence flags). A file is streamed: read, estimated and written
chunk by chunk (``stream.CHUNK_ROWS`` rows), so memory does not grow with it.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.errors import ConfigError, UserError
from hapticlab.core.host.interfaces import cov_diag_of, params_of
from hapticlab.core.host.registry import Registry
from hapticlab.core.types import Estimates
from hapticlab.sessions.config import parse_value
from hapticlab.sessions.offline.metrics import RmsAfterConvergence
from hapticlab.sessions.offline.numerics import numerical_failures
from hapticlab.sessions.output import atomic_output, check_output, write_text
from hapticlab.sessions.recording.csvimport import COMPENSATED_HEADER, write_compensated_rows
from hapticlab.sessions.recording.loader import iter_stream
from hapticlab.sessions.recording.stream import Stream, concat_samples, unused_note

BLOCK = 1024
"""Usable samples per estimator call offline, counted across chunks (the result does not depend on the chunking)."""


def estimator_options(overrides: list[str]) -> dict[str, Any]:
    """Estimator options from ``--set estimator.key=value`` (or ``key=value``).

    ``estimator.name=...`` is returned under ``name`` (it picks the estimator).
    """
    options: dict[str, Any] = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected key=value, e.g. estimator.force_threshold=2")
        if key.startswith("estimator."):
            key = key[len("estimator.") :]
        elif "." in key:
            raise ConfigError(f"{key}: compensate takes estimator options only (estimator.<option>=value)")
        options[key] = parse_value(value, key)
    return options


class _Pending:
    """One chunk on its way through :func:`estimate_chunks`: its estimate arrays, filled block by block."""

    def __init__(self, stream: Stream, offset: int):
        self.stream, self.offset = stream, offset
        n = len(stream)
        self.ok = stream.samples.usable
        self.usable = np.flatnonzero(self.ok)
        self.left = len(self.usable)  # usable rows not yet estimated
        self.force, self.torque = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        self.contact, self.conv_f, self.conv_t = (np.zeros(n, dtype=bool) for _ in range(3))

    def fill(self, rows: np.ndarray, est: Estimates, a: int, b: int) -> None:
        self.force[rows], self.torque[rows], self.contact[rows] = (
            est.contact_force_S[a:b],
            est.contact_torque_S[a:b],
            est.contact[a:b],
        )
        self.conv_f[rows], self.conv_t[rows] = est.converged_force[a:b], est.converged_torque[a:b]
        self.left -= len(rows)

    def finish(self, carry: tuple[bool, bool]) -> Estimates:
        """The chunk's estimates; rows the estimator did not see keep the flags of the usable row before
        them (``carry``: the flags of the previous chunks' last usable row)."""
        n = len(self.ok)
        if len(self.usable) < n:
            last = np.maximum.accumulate(np.where(self.ok, np.arange(n), -1))
            seen = last >= 0
            self.conv_f[seen], self.conv_t[seen] = self.conv_f[last[seen]], self.conv_t[last[seen]]
            self.conv_f[~seen], self.conv_t[~seen] = carry
        return Estimates(self.stream.samples.t_ns, self.force, self.torque, self.contact, self.conv_f, self.conv_t)


def estimate_chunks(
    chunks: Iterable[Stream], estimator: Any, progress=None, total: int | None = None
) -> Iterator[tuple[Stream, Estimates]]:
    """Feed the usable rows of consecutive chunks through the estimator; yield each chunk with its estimates.

    The estimator gets blocks of :data:`BLOCK` usable rows counted across chunk
    boundaries (a block may span two chunks), so the estimates do not depend on
    how the input was cut. A chunk is yielded as soon as its last usable row is
    estimated, one estimate row per row: rows the estimator may not see get NaN
    wrench values, no contact, and the convergence flags of the usable row
    before them. A ``LinAlgError`` inside the estimator is a
    :class:`~.numerics.NumericalError` naming the file and the rows.
    """
    waiting: deque[_Pending] = deque()  # chunks not yet yielded, in order
    queue: deque[tuple[_Pending, np.ndarray]] = deque()  # usable rows not yet fed, by chunk
    queued = 0
    offset = 0
    carry = (False, False)

    def feed(count: int) -> None:
        parts: list[tuple[_Pending, np.ndarray]] = []
        while count:
            chunk, rows = queue[0]
            part = rows[:count]
            if len(part) == len(rows):
                queue.popleft()
            else:
                queue[0] = (chunk, rows[count:])
            parts.append((chunk, part))
            count -= len(part)
        block = concat_samples([chunk.stream.samples.subset(part) for chunk, part in parts])
        first, last = parts[0][0].offset + parts[0][1][0] + 1, parts[-1][0].offset + parts[-1][1][-1] + 1
        with numerical_failures(f"{parts[0][0].stream.name} rows {first}-{last}", "the estimator"):
            est = estimator.update_block(block)
        a = 0
        for chunk, part in parts:
            chunk.fill(part, est, a, a + len(part))
            a += len(part)
        if progress is not None:
            progress(int(last), total)

    def ready() -> Iterator[tuple[Stream, Estimates]]:
        nonlocal carry
        while waiting and waiting[0].left == 0:
            chunk = waiting.popleft()
            est = chunk.finish(carry)
            if len(est):
                carry = (bool(est.converged_force[-1]), bool(est.converged_torque[-1]))
            yield chunk.stream, est

    for stream in chunks:
        chunk = _Pending(stream, offset)
        offset += len(stream)
        waiting.append(chunk)
        if chunk.left:
            queue.append((chunk, chunk.usable))
            queued += chunk.left
        while queued >= BLOCK:
            feed(BLOCK)
            queued -= BLOCK
        yield from ready()
    if queued:
        feed(queued)
    yield from ready()


def run_estimator(stream: Stream, estimator: Any, progress=None) -> Estimates:
    """Feed the usable rows through the estimator in blocks; one estimate row per input row.

    Rows the estimator may not see get NaN wrench values, no contact, and the
    convergence flags of the row before them.
    """
    ((_, est),) = estimate_chunks([stream], estimator, progress, total=len(stream))
    return replace(est, params=params_of(estimator), cov_diag=cov_diag_of(estimator))


@dataclass
class CompensateResult:
    """What ``compensate`` did, for the summary it prints."""

    rows: int
    estimates: Estimates | None
    """every row's estimates (None when ``compensate`` was asked not to keep them)"""
    params: dict[str, Any]
    rms_force_S: list[float]
    """per-axis RMS of the contact force over no-contact rows after the first convergence, N"""
    rms_torque_S: list[float]
    first_converged_force: int | None
    first_converged_torque: int | None
    notes: list[str]


@contextmanager
def _output(path: Path) -> Iterator[Callable[[np.ndarray, Estimates], None]]:
    """A writer of output rows into ``path``: Parquet for a ``.parquet`` name, else the CSV."""
    if path.suffix.lower() == ".parquet":
        from hapticlab.sessions.recording.parquetio import CompensatedParquet

        table = CompensatedParquet(path)
        try:
            yield table.write
        finally:
            table.close()
        return
    with path.open("w", newline="", encoding="utf-8") as fh:
        fh.write(COMPENSATED_HEADER)
        yield lambda t_s, est: write_compensated_rows(fh, t_s, est)


def compensate(
    recording: str | Path | Stream,
    out_csv: str | Path,
    estimator_name: str = "rls",
    overrides: list[str] | None = None,
    params_out: str | Path | None = None,
    registry: Registry | None = None,
    progress=None,
    force: bool = False,
    keep_estimates: bool = True,
) -> CompensateResult:
    """Run ``estimator_name`` over a recording (a stream, or a CSV, Parquet or MCAP file) and write the contact
    wrench per row to ``out_csv`` (a CSV, or Parquet when its name ends in ``.parquet``).

    A file is streamed chunk by chunk; with ``keep_estimates`` false nothing
    grows with its length (the result's ``estimates`` is None). The outputs are
    checked before the work (an existing file is refused unless ``force``) and
    written whole or not at all (``sessions.output``).
    """
    registry = registry if registry is not None else Registry()
    options = estimator_options(overrides or [])
    estimator_name = options.pop("name", estimator_name)
    source = recording.source if isinstance(recording, Stream) else str(recording)
    out_csv = check_output(out_csv, force, label="-o", inputs=[source])
    if params_out:
        params_out = check_output(params_out, force, label="--params-out", inputs=[source])
        if Path(params_out).resolve() == out_csv.resolve():
            raise UserError(f"--params-out {params_out}: the same file as -o; give another")
    estimator = registry.create("estimator", estimator_name, options, where="estimator")
    chunks = [recording] if isinstance(recording, Stream) else iter_stream(recording)
    scored_f, scored_t = RmsAfterConvergence(), RmsAfterConvergence()
    notes: list[str] = []
    parts: list[Estimates] = []
    unused = 0
    with atomic_output(out_csv, force, label="-o") as tmp, _output(tmp) as write:
        for chunk, est in estimate_chunks(chunks, estimator, progress):
            write(chunk.t_s, est)
            scored_f.add(est.contact_force_S, est.contact, est.converged_force)
            scored_t.add(est.contact_torque_S, est.contact, est.converged_torque)
            notes += chunk.notes
            unused += int(np.count_nonzero(~chunk.samples.usable))
            if keep_estimates:
                parts.append(est)
    if not isinstance(recording, Stream):
        notes += unused_note(Path(source).name, unused)
    rows = scored_f.rows
    params: dict[str, Any] = dict(params_of(estimator))
    params.update(
        {
            "estimator": estimator_name,
            "samples": rows,
            "first_converged_force": scored_f.first,
            "first_converged_torque": scored_t.first,
            "cov_diag": cov_diag_of(estimator),
        }
    )
    if params_out:
        write_text(params_out, json.dumps(params, indent=2) + "\n", force, label="--params-out")
    estimates = Estimates.concatenate(parts, params_of(estimator), cov_diag_of(estimator)) if keep_estimates else None
    return CompensateResult(
        rows, estimates, params, scored_f.value.tolist(), scored_t.value.tolist(), scored_f.first, scored_t.first, notes
    )
