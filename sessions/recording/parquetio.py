"""Parquet in and out: a recording with the CSV import contract's columns, and ``compensate``'s output.

A Parquet recording holds the columns of the CSV contract (:mod:`.csvimport`),
each numeric (float or integer; ``t`` in s, the wrench in N and N·m, the
quaternion of E in B, optional ``px,py,pz`` in m and ``q1..q6`` in rad), as
pandas' ``to_parquet`` or DuckDB's ``COPY ... TO 'x.parquet'`` write them. It is
checked as a CSV is, the messages naming the data row (from 1) where a CSV's
name the line: a missing or non-numeric required column, a null or non-finite
cell, a non-unit quaternion, a non-increasing ``t``; a row that repeats the row
before it in every column read is dropped with a note. It is read a row group at
a time (batches of ``rows``), so memory follows the file's row groups, not its
length.

``compensate -o out.parquet`` writes :data:`~.csvimport.OUTPUT_COLUMNS`: ``t`` and
the contact wrench as float64 at full precision (the CSV rounds the wrench to 9
digits), the three flags as int8 0/1.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.types import Estimates
from hapticlab.sessions.recording.csvimport import OUTPUT_COLUMNS, REQUIRED, ChunkParser, CsvError
from hapticlab.sessions.recording.stream import CHUNK_ROWS, Stream

WRITE_ROWS = 1 << 17
"""Rows per row group written (a few MiB: what pandas and DuckDB read well)."""


def iter_parquet(path: str | Path, rows: int = CHUNK_ROWS) -> Iterator[Stream]:
    """A Parquet recording as consecutive streams of at most ``rows`` rows, as :func:`~.csvimport.iter_csv`
    gives a CSV (``t_ns`` from the first ``t``, ``seq`` the row number, the notes on the first)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    name = path.name
    try:
        pf = pq.ParquetFile(path)
    except OSError as exc:
        raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (pa.ArrowException, ValueError) as exc:
        raise CsvError(f"{name}: not a Parquet file ({str(exc).splitlines()[0]})") from None
    schema = pf.schema_arrow
    header = list(schema.names)
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise CsvError(f"{name}: missing required column(s) {', '.join(missing)} (required: {','.join(REQUIRED)})")
    chunk = ChunkParser(path, header, 0)
    chunk.unit = "row"
    used = [c for c in header if c in chunk.used]
    for col in used:
        kind = schema.field(col).type
        if not (pa.types.is_floating(kind) or pa.types.is_integer(kind)):
            raise CsvError(f"{name}: column {col!r} holds {kind}, not numbers")
    done = 0
    last: np.ndarray | None = None  # the previous batch's last row (a repeat may follow it)
    try:
        batches = pf.iter_batches(batch_size=rows, columns=used)
        for batch in batches:
            values = {col: _floats(batch.column(col), name, col, done) for col in used}
            table = np.column_stack([values[c] for c in used])
            if not len(table):
                continue
            repeat = np.r_[False if last is None else bool((table[0] == last).all()), (table[1:] == table[:-1]).all(1)]
            last = table[-1]
            n = len(table)
            keep = np.flatnonzero(~repeat)
            notes = _repeat_note(name, done + 1 + np.flatnonzero(repeat))
            t = values["t"][keep]

            def columns(cols, keep=keep, values=values) -> np.ndarray:
                return np.column_stack([values[c][keep] for c in cols])

            stream = chunk.build(t, done + 1 + keep, done + keep, notes, columns)
            done += n
            yield stream
    except (pa.ArrowException, OSError) as exc:
        raise CsvError(f"{name}: cannot read it past row {done} ({str(exc).splitlines()[0]})") from None
    if done == 0:
        raise CsvError(f"{name}: no data rows")


def _floats(column: Any, name: str, col: str, done: int) -> np.ndarray:
    """A numeric column as float64; CsvError naming the first null or non-finite cell's row."""
    values = column.to_numpy(zero_copy_only=False).astype(float)  # a null becomes NaN
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        k = int(bad[0])
        cell = "null" if column[k].as_py() is None else repr(float(values[k]))
        raise CsvError(f"{name} row {done + k + 1}, column {col!r}: {cell} is not a finite number")
    return values


def _repeat_note(name: str, at: np.ndarray) -> list[str]:
    if not len(at):
        return []
    where = ", ".join(map(str, at[:10].tolist())) + (f" and {len(at) - 10} more" if len(at) > 10 else "")
    return [f"{name}: dropped {len(at)} row(s) that exactly repeat the row before them (row(s) {where})"]


class CompensatedParquet:
    """``compensate``'s output as a Parquet file: :meth:`write` batches, :meth:`close` at the end."""

    def __init__(self, path: Path):
        import pyarrow as pa
        import pyarrow.parquet as pq

        self.pa = pa
        fields = [(c, pa.float64()) for c in OUTPUT_COLUMNS[:7]] + [(c, pa.int8()) for c in OUTPUT_COLUMNS[7:]]
        self.schema = pa.schema(fields)
        self.writer = pq.ParquetWriter(path, self.schema, compression="zstd")
        self.parts: list[Any] = []
        self.rows = 0

    def write(self, t_s: np.ndarray, est: Estimates) -> None:
        """Append rows (the estimated contact wrench in S and the flags, one row per input row)."""
        force, torque = np.asarray(est.contact_force_S, float), np.asarray(est.contact_torque_S, float)
        arrays = [np.asarray(t_s, float), *force.T, *torque.T]
        arrays += [np.asarray(f).astype(np.int8) for f in (est.contact, est.converged_force, est.converged_torque)]
        self.parts.append(self.pa.RecordBatch.from_arrays(arrays, schema=self.schema))
        self.rows += len(t_s)
        if self.rows >= WRITE_ROWS:
            self.flush()

    def flush(self) -> None:
        if self.parts:
            self.writer.write_table(self.pa.Table.from_batches(self.parts), row_group_size=WRITE_ROWS)
        self.parts, self.rows = [], 0

    def close(self) -> None:
        self.flush()
        self.writer.close()
