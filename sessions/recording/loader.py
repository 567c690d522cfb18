"""Any recording as a :class:`~.stream.Stream`: a CSV (the import contract), a Parquet file with the same columns
or an MCAP file, by its suffix."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from hapticlab.sessions.recording.csvimport import CsvError, iter_csv
from hapticlab.sessions.recording.mcapimport import iter_mcap
from hapticlab.sessions.recording.parquetio import iter_parquet
from hapticlab.sessions.recording.stream import CHUNK_ROWS, Stream, unused_note


def load_stream(path: str | os.PathLike[str]) -> Stream:
    """Read a CSV (import contract), a Parquet file with its columns (``.parquet``) or an MCAP recording
    (``.mcap``) into a stream."""
    stream = Stream.concatenate(list(iter_stream(path)))
    stream.notes += unused_note(stream.name, int(np.count_nonzero(~stream.samples.usable)))
    return stream


def iter_stream(path: str | os.PathLike[str], rows: int = CHUNK_ROWS) -> Iterator[Stream]:
    """A CSV, Parquet or MCAP file as consecutive streams of at most ``rows`` rows, read as they are asked for.

    Memory stays a small multiple of one chunk (plus, for an MCAP file, the
    pose stream as arrays). The chunks concatenated are :func:`load_stream`'s
    stream, but for the note on unused samples (:func:`~.stream.unused_note`: count them as they go).
    """
    path = Path(path)
    if not path.exists():
        raise CsvError(f"{path}: no such file")
    if not path.is_file() and not path.is_dir():  # a folder: the reader's own one line
        raise CsvError(f"{path}: not a regular file (a device, a FIFO or a socket); give a CSV or MCAP file")
    if path.suffix.lower() == ".mcap":
        return iter_mcap(path, rows)
    if path.suffix.lower() == ".parquet":
        return iter_parquet(path, rows)
    return iter_csv(path, rows)
