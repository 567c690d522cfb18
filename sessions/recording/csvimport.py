"""The CSV import contract: raw wrench and robot orientation per row, read into a :class:`Stream`.

Header row, comma separated: ``t`` (s, increasing), ``fx,fy,fz`` (N) and
``tx,ty,tz`` (N·m) raw sensor wrench in S, ``qw,qx,qy,qz`` unit quaternion of
E in B (forward kinematics, i.e. R_BE), optional ``px,py,pz`` (m, E origin in
B), optional joint columns ``q1..q6`` (rad). Unknown extra columns are ignored
with a note. A row that repeats the row before it exactly (every cell the same:
a logger that wrote a record twice) is dropped, with a note saying how many and
at which lines. A missing or non-numeric required column, a non-unit quaternion
or a non-increasing ``t`` (a repeated time with other values: a conflicting
duplicate) is a ``CsvError`` naming the file, line and column.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterator
from itertools import islice
from pathlib import Path
from typing import TextIO

import numpy as np

from hapticlab.core.errors import UserError
from hapticlab.core.frames import matrix_from_quat_wxyz
from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.sessions.recording import csvfast
from hapticlab.sessions.recording.stream import CHUNK_ROWS, Stream, off_unit

REQUIRED = ("t", "fx", "fy", "fz", "tx", "ty", "tz", "qw", "qx", "qy", "qz")
POSITION = ("px", "py", "pz")
JOINTS = tuple(f"q{i}" for i in range(1, 7))
MAX_LINE_CHARS = 1 << 20
"""Characters a line may hold (a row of samples holds ~300): a longer one is no CSV of samples, and reading
it whole would take the memory of the whole line (a 4 GiB file of NUL bytes has one line)."""


class CsvError(UserError, ValueError):
    """A CSV file breaks the import contract; the message names file, line and column."""


def read_csv(path: str | Path) -> Stream:
    """Import a CSV file that follows the contract as an offline stream.

    Every row is a sample: ``t_ns`` counts from the first row's ``t``, ``seq``
    is the row number, status good and nothing stale; R_EB is the transpose of
    the quaternion's R_BE. Joint columns, when present, ride along as ``joints``.
    """
    return Stream.concatenate(list(iter_csv(path)))


def iter_csv(path: str | Path, rows: int = CHUNK_ROWS) -> Iterator[Stream]:
    """The file as consecutive streams of at most ``rows`` rows each, read as they are asked for.

    Memory stays a small multiple of one chunk whatever the file's size. Each
    chunk is checked as :func:`read_csv` checks the file (the line numbers are
    the file's; ``t`` must increase across chunks too); ``t_ns`` counts from
    the file's first ``t`` and ``seq`` is the row number in the file. The
    first chunk carries the notes.

    Plain chunks (ASCII, one record a line, every cell a finite number, ``t``
    strictly increasing) are parsed by pyarrow's CSV parser (:mod:`.csvfast`);
    from the first chunk that is not, the rest of the file is read by Python's
    ``csv`` module and checked cell by cell, so every message is the same.
    """
    path = Path(path)
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None
    with fh:
        try:
            header = csvfast.read_header(fh, MAX_LINE_CHARS)
        except OSError as exc:
            raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None
        records: Iterator[tuple[int, list[str]]] = iter(())
        if header is None:  # an unusual first line (or none): the whole file the careful way
            fh.seek(0)
            records = _text_records(fh, path, "utf-8-sig", 1)
            first = next(records, None)
            if first is None:
                raise CsvError(f"{path.name}: empty file; expected a header row with {','.join(REQUIRED)}")
            chunk = ChunkParser(path, [h.strip() for h in first[1]], first[0])
        else:
            chunk = ChunkParser(path, header, 1)
        done = 0
        blocks = csvfast.Blocks(fh, rows, MAX_LINE_CHARS) if header is not None else None
        while blocks is not None:
            try:
                block = blocks.next()
            except OSError as exc:
                raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None
            if block is None:
                break
            stream = csvfast.parse(chunk, block, done)
            if stream is None:  # not plain: the rest of the file the careful way, from this block's first line
                fh.seek(block.offset)
                records = _text_records(fh, path, "utf-8", block.line)
                break
            done += len(block)
            yield stream
            del stream
        while batch := list(islice(records, rows)):
            stream = chunk.parse(batch, done)
            done += len(batch)
            del batch  # one chunk's rows (Python strings: ~1 kB a row) in memory at a time
            yield stream
            del stream
        if done == 0:
            raise CsvError(f"{path.name}: no data rows after the header")


def _text_records(fh, path: Path, encoding: str, line: int) -> Iterator[tuple[int, list[str]]]:
    """The records of ``fh`` from where it stands (line number ``line``), read by the ``csv`` module."""
    text = io.TextIOWrapper(fh, encoding=encoding, newline="")
    return _records(csv.reader(_bounded_lines(text, path.name, line - 1)), path, line - 1)


def _bounded_lines(fh: TextIO, name: str, n: int = 0) -> Iterator[str]:
    """The file's lines (after line ``n``), each read up to ``MAX_LINE_CHARS``; CsvError at a longer one."""
    while line := fh.readline(MAX_LINE_CHARS + 1):
        n += 1
        if len(line) > MAX_LINE_CHARS:
            raise CsvError(f"{name} line {n}: longer than {MAX_LINE_CHARS:,} characters: not a CSV of samples")
        yield line


def _records(reader, path: Path, before: int = 0) -> Iterator[tuple[int, list[str]]]:
    """(line number, cells) of every row after line ``before`` that is not blank (a trailing newline or two are
    no rows)."""
    n = before
    try:
        for n, row in enumerate(reader, start=before + 1):
            if any(cell.strip() for cell in row):
                yield n, row
    except UnicodeDecodeError:
        raise CsvError(f"{path.name}: not a text CSV file") from None
    except csv.Error as exc:
        raise CsvError(f"{path.name} line {n + 1}: {exc}") from None
    except OSError as exc:
        raise CsvError(f"{path}: cannot read: {exc.strerror or exc}") from None


class ChunkParser:
    """Parses consecutive batches of rows of one file into streams, carrying what spans them."""

    def __init__(self, path: Path, header: list[str], line: int):
        name = self.name = path.name
        self.source = str(path)
        self.header, self.index = header, {h: i for i, h in enumerate(header)}
        missing = [c for c in REQUIRED if c not in self.index]
        if missing:
            raise CsvError(
                f"{name} line {line}: missing required column(s) {', '.join(missing)} (required: {','.join(REQUIRED)})"
            )
        self.has_position = all(c in self.index for c in POSITION)
        self.joint_cols = [c for c in JOINTS if c in self.index]
        known = set(REQUIRED) | (set(POSITION) if self.has_position else set()) | set(self.joint_cols)
        ignored = [h for h in header if h not in known]
        self.used = known
        """the columns read"""
        self.notes = [f"{name}: ignoring column(s) {', '.join(ignored)}"] if ignored else []
        """for the first chunk"""
        self.unit = "line"
        """what the numbers in messages count (a Parquet file's: "row")"""
        self.t0: float | None = None  # the file's first t: t_ns counts from it
        self.last: tuple[int, float] | None = None  # (line, t) of the previous chunk's last row
        self.last_cells: list[str] | bytes | None = None  # ... and its cells, or its line (a duplicate may follow it)

    def column(self, col: str, lines: list[int], data: list[list[str]]) -> np.ndarray:
        values = [row[self.index[col]].strip() for row in data]
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
                raise CsvError(f"{self.name} line {n}, column {col!r}: {text!r} is not a finite number")
        raise AssertionError("unreachable")

    def parse(self, batch: list[tuple[int, list[str]]], offset: int) -> Stream:
        name = self.name
        lines = [n for n, _ in batch]
        data = [row for _, row in batch]
        for n, row in zip(lines, data):
            if len(row) != len(self.header):
                raise CsvError(f"{name} line {n}: {len(row)} fields, the header has {len(self.header)}")

        def columns(cols) -> np.ndarray:
            return np.column_stack([self.column(c, lines, data) for c in cols])

        t = self.column("t", lines, data)
        rows = np.arange(offset, offset + len(batch))
        t, lines, data, rows, notes = self._drop_exact_duplicates(t, lines, data, rows)
        stream = self.build(t, lines, rows, notes, columns)
        if len(t):  # (a batch that only repeated the row before it leaves the last row as it was)
            self.last_cells = data[-1]
        return stream

    def build(self, t: np.ndarray, lines, rows: np.ndarray, notes: list[str], columns) -> Stream:
        """The stream of a batch whose cells are numbers: ``t`` is checked against the rows before (``lines``,
        their line numbers), then each column asked of ``columns`` (names -> (n, k) floats), then the
        quaternions; the first chunk carries the header's notes."""
        name = self.name
        t_all, lines_all = (t, lines) if self.last is None else (np.r_[self.last[1], t], [self.last[0], *lines])
        bad = np.flatnonzero(np.diff(t_all) <= 0)
        if len(bad):
            k = int(bad[0])
            if t_all[k + 1] == t_all[k]:
                raise CsvError(
                    f"{name} {self.unit} {lines_all[k + 1]}, column 't': {float(t_all[k + 1])!r} repeats the "
                    f"time of {self.unit} {lines_all[k]} with other values (a conflicting duplicate; rows "
                    f"repeated exactly are dropped)"
                )
            raise CsvError(
                f"{name} {self.unit} {lines_all[k + 1]}, column 't': {float(t_all[k + 1])!r} does not increase "
                f"(previous {float(t_all[k])!r})"
            )
        force_S = columns(("fx", "fy", "fz"))
        torque_S = columns(("tx", "ty", "tz"))
        quat = columns(("qw", "qx", "qy", "qz"))
        norm = np.linalg.norm(quat, axis=1)
        if (off := off_unit(norm)) is not None:
            raise CsvError(
                f"{name} {self.unit} {lines[off]}, columns qw,qx,qy,qz: not a unit quaternion (norm {norm[off]:.6g})"
            )
        quat = quat / norm[:, None]
        p = columns(POSITION) if self.has_position else None
        joints = columns(self.joint_cols) if self.joint_cols else None
        if self.t0 is None:
            self.t0 = float(t[0])
        if len(t):
            self.last = (int(lines[-1]), float(t[-1]))
        notes, self.notes = self.notes + notes, []
        n = len(t)
        t_ns = np.round((t - self.t0) * 1e9).astype(np.int64)
        R_EB = matrix_from_quat_wxyz(quat).transpose(0, 2, 1)
        samples = AlignedSamples(
            t_ns, force_S, torque_S, R_EB, rows, np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool), quat, p
        )
        return Stream(t, samples, notes, self.source, joints)

    def _drop_exact_duplicates(self, t, lines, data, rows):
        """The batch without the rows that repeat the row before them cell for cell, and a note naming them.

        Only a row whose ``t`` equals the previous row's can be one; its cells are compared as written
        (stripped), the previous chunk's last row included. ``rows`` (the data-row numbers, the samples'
        ``seq``) keep their gaps, so a dropped row stays visible."""
        prev_t = np.r_[self.last[1] if self.last is not None else np.nan, t[:-1]]
        same_t = np.flatnonzero(t == prev_t)
        if isinstance(self.last_cells, bytes):  # the previous chunk was parsed whole (csvfast): its last line
            self.last_cells = next(csv.reader([self.last_cells.decode()]))
        dropped = [
            k
            for k in same_t
            if [c.strip() for c in data[k]] == [c.strip() for c in (data[k - 1] if k > 0 else self.last_cells or [])]
        ]
        if not dropped:
            return t, lines, data, rows, []
        keep = np.ones(len(t), dtype=bool)
        keep[dropped] = False
        at = [lines[k] for k in dropped]
        where = ", ".join(map(str, at[:10])) + (f" and {len(at) - 10} more" if len(at) > 10 else "")
        note = f"{self.name}: dropped {len(at)} row(s) that exactly repeat the row before them (line(s) {where})"
        kept = np.flatnonzero(keep)
        return t[keep], [lines[k] for k in kept], [data[k] for k in kept], rows[keep], [note]


OUTPUT_COLUMNS = ("t", "fx", "fy", "fz", "tx", "ty", "tz", "contact", "converged_force", "converged_torque")
COMPENSATED_HEADER = ",".join(OUTPUT_COLUMNS) + "\n"


_ROW_FORMAT = "%r," + ",".join(["%.9g"] * 6) + ",%d,%d,%d\n"
"""t keeps full precision (``repr``: epoch seconds need 16 digits); the wrench 9 significant digits."""


def write_compensated_rows(fh: TextIO, t_s: np.ndarray, est: Estimates) -> None:
    """Write rows of the ``compensate`` output (after :data:`COMPENSATED_HEADER`): the estimated
    contact wrench in S and the flags, one row per input row, in the order given.

    Rows the estimator could not use (non-finite, stale or flagged by the
    sensor) carry NaN wrench values. The rows are formatted by one ``%`` over
    the whole batch (C's loop, no Python per row), exactly as ``f"{t!r}"`` and
    ``f"{v:.9g}"`` would write each value.
    """
    n = len(t_s)
    flags = np.column_stack([est.contact, est.converged_force, est.converged_torque])
    table = np.column_stack([t_s, est.contact_force_S, est.contact_torque_S, flags])  # flags as 0.0/1.0 for %d
    for a in range(0, n, _WRITE_ROWS):
        part = table[a : a + _WRITE_ROWS]
        fh.write((_ROW_FORMAT * len(part)) % tuple(part.ravel().tolist()))


_WRITE_ROWS = 4096
"""Rows formatted at a time (the text of a batch is held whole before it is written)."""
