"""The CSV reader's fast lane: plain blocks of lines parsed whole by pyarrow's CSV parser.

:func:`~.csvimport.iter_csv` reads a file in blocks of whole lines (:class:`Blocks`,
bytes; no Python object per row) and hands each to :func:`parse`. A block that
is plain - ASCII, one record a line, no quotes, no blank line, every used cell
a finite number, ``t`` strictly increasing within it and from the block before
- becomes a stream here; any other block returns None, and the file is read
from that block's first line on by the ``csv`` module, cell by cell, which
names the line and column of what is wrong (or drops a repeated row). Either
way the numbers are the same: pyarrow parses a decimal to the nearest double,
as ``float()`` does.

pyarrow rather than ``np.loadtxt``: it parses only the columns the contract
uses (an ignored column may hold text), and it was the faster of the two on
blocks of the contract when it was chosen (the figures are in that commit).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import IO, TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from hapticlab.sessions.recording.stream import Stream

READ_BYTES = 1 << 20
"""Bytes read at a time."""
MAX_BLOCK_BYTES = 64 << 20
"""A block of lines that grows past this before it holds its rows is no plain CSV of samples (rows of the
contract take ~300 bytes): the careful reader takes over, with its own bound on a line."""
BOM = b"\xef\xbb\xbf"


def read_header(fh: IO[bytes], max_line: int) -> list[str] | None:
    """The header's cells when the file starts with a plain header line (ASCII after an optional UTF-8 BOM,
    no quote, ends in a newline, not blank), else None (the careful reader reads the whole file)."""
    line = fh.readline(max_line + 1)
    if line.startswith(BOM):
        line = line[len(BOM) :]
    if not _plain(line) or not line.endswith(b"\n") or not line.strip(b" \t,\r\n"):
        return None
    return [h.strip() for h in line.decode("ascii").rstrip("\r\n").split(",")]


def _plain(data: bytes) -> bool:
    """ASCII, no quote or NUL, and a carriage return only before a newline."""
    if not data.isascii() or b'"' in data or b"\0" in data:
        return False
    return b"\r" not in data or data.count(b"\r") == data.count(b"\r\n")


@dataclass
class Block:
    """Consecutive whole lines of a file: ``data`` starts at byte ``offset``, on line number ``line``."""

    data: bytes
    offset: int
    line: int
    lines: int
    """how many lines ``data`` holds (the last may lack its newline at the file's end)"""

    def __len__(self) -> int:
        return self.lines


class Blocks:
    """The rest of a binary file (after its header) as blocks of ``rows`` lines (fewer at its end).

    Stops early (and the caller takes over from the last block's start) when a
    block would pass :data:`MAX_BLOCK_BYTES`: the last block returned is then the
    partial one, which :func:`parse` refuses.
    """

    def __init__(self, fh: IO[bytes], rows: int, max_line: int):
        self.fh, self.rows, self.max_line = fh, rows, max_line
        self.offset = fh.tell()
        self.line = 2
        self.buffer = b""
        self.eof = False

    def next(self) -> Block | None:
        parts, count = [self.buffer], self.buffer.count(b"\n")
        size = len(self.buffer)
        while count < self.rows and not self.eof and size <= MAX_BLOCK_BYTES:
            more = self.fh.read(READ_BYTES)
            if not more:
                self.eof = True
            parts.append(more)
            count += more.count(b"\n")
            size += len(more)
        data = b"".join(parts)
        if not data:
            return None
        if count >= self.rows:
            ends = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10)
            cut, lines = int(ends[self.rows - 1]) + 1, self.rows
        elif self.eof:
            cut, lines = len(data), count + (not data.endswith(b"\n"))
        else:  # too big: handed over whole (parse refuses it)
            cut, lines = len(data), 0
        if lines and cut > self.max_line:  # a line longer than the careful reader allows: it takes the block
            ends = np.flatnonzero(np.frombuffer(data, dtype=np.uint8, count=cut) == 10)  # (and names the line)
            if np.diff(np.concatenate(([-1], ends, [cut - 1]))).max() > self.max_line:
                lines = 0
        block = Block(data[:cut], self.offset, self.line, lines)
        self.buffer = data[cut:]
        self.offset += cut
        self.line += lines
        return block


def parse(chunk: Any, block: Block, offset: int) -> Stream | None:
    """The block as a stream of ``chunk`` (a :class:`~.csvimport.ChunkParser`: the header and what spans blocks),
    its rows numbered from ``offset``; None when the block is not plain (the careful reader takes it)."""
    if not block.lines or not _plain(block.data):
        return None
    import pyarrow as pa
    import pyarrow.csv as pacsv

    names = [f"c{i}" for i in range(len(chunk.header))]  # a header may repeat a name: columns by position
    used = {col: names[i] for col, i in chunk.index.items() if col in chunk.used}
    try:
        table = pacsv.read_csv(
            pa.BufferReader(block.data),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=False, block_size=len(block.data) + 1),
            parse_options=pacsv.ParseOptions(quote_char=False, newlines_in_values=False),
            convert_options=pacsv.ConvertOptions(
                column_types={name: pa.float64() for name in used.values()},
                include_columns=sorted(set(used.values())),
                null_values=[],
                strings_can_be_null=False,
            ),
        )
    except pa.ArrowInvalid:  # a cell that is no number, a row of other length
        return None
    if table.num_rows != block.lines:  # a blank line
        return None
    values = {col: table.column(name).to_numpy() for col, name in used.items()}
    if not all(np.isfinite(v).all() for v in values.values()):
        return None
    t = values["t"]
    t_all = t if chunk.last is None else np.r_[chunk.last[1], t]
    if np.any(t_all[1:] == t_all[:-1]):  # a repeated time: the careful reader drops or names it
        return None

    def columns(cols) -> np.ndarray:
        return np.column_stack([values[c] for c in cols])

    lines = block.line + np.arange(block.lines)
    rows = np.arange(offset, offset + block.lines)
    stream = chunk.build(t, lines, rows, [], columns)
    chunk.last_cells = block.data[block.data.rstrip(b"\r\n").rfind(b"\n") + 1 :].rstrip(b"\r\n")
    return stream
