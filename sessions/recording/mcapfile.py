"""An MCAP file checked and opened: :class:`RecordingError`, its one-line messages, the file's summary.

A file that is not MCAP, or is truncated or damaged, is a :class:`RecordingError`
with one line that says what is wrong and to run ``hapticlab recover``. The
summary (channels, schemas, message counts, chunk indexes) is parsed once per
version of a file; :func:`read_head` and :func:`file_stats` answer from it
without reading a message. :func:`log_offset` is what every reader subtracts
from a log time to give a message's time on the session clock (the session's
``clock_offset_ns``: log times are Unix time; 0 in older files).
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.opcode import Opcode
from mcap.reader import McapReader, make_reader
from mcap.records import Channel

from hapticlab.core.errors import UserError
from hapticlab.sessions.recording.cdr_layouts import CDR_BLOCK_SCHEMAS
from hapticlab.sessions.recording.metadata import clock_offset
from hapticlab.sessions.recording.schemas import BLOCK_SCHEMA_TITLES, MCAP_MAGIC, SESSION_METADATA


class RecordingError(UserError, ValueError):
    """A recording that cannot be read: not an MCAP file, truncated or corrupt."""


def recover_hint(path: Path) -> str:
    return f"run `hapticlab recover {path} -o FIXED.mcap` to salvage it"


def _truncated(path: Path) -> RecordingError:
    return RecordingError(f"{path} is truncated (no MCAP footer; the writer probably died): {recover_hint(path)}")


def json_loads(data: bytes | str) -> Any:
    """``json.loads``; JSON nested past the parser's recursion limit is a ``JSONDecodeError`` like any other bad
    JSON (a hostile file's 100,000 brackets are not a ``RecursionError`` traceback)."""
    try:
        return json.loads(data)
    except RecursionError:
        raise json.JSONDecodeError("nested too deeply", "", 0) from None


def damaged(path: Path, exc: BaseException) -> RecordingError:
    detail = str(exc).replace("\n", " ") or type(exc).__name__
    return RecordingError(f"{path} is a damaged MCAP file ({detail}): {recover_hint(path)}")


def check_mcap(path: Path) -> None:
    """RecordingError unless ``path`` is a regular file that starts and ends with the MCAP magic and has a footer
    (a device or a FIFO is refused before it is opened: reading one never ends or blocks)."""
    if path.exists() and not path.is_file():
        raise RecordingError(f"{path}: not a regular file (a folder, a device or a FIFO); give an MCAP file")
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
        if head != MCAP_MAGIC:
            raise RecordingError(f"{path} is not an MCAP file (bad magic bytes at the start)")
        footer_len = 1 + 8 + 20  # opcode, length, Footer body
        if size < 2 * len(MCAP_MAGIC) + footer_len:
            raise _truncated(path)
        f.seek(size - len(MCAP_MAGIC) - footer_len)
        tail = f.read()
    if tail[-len(MCAP_MAGIC) :] != MCAP_MAGIC or tail[0] != Opcode.FOOTER:
        raise _truncated(path)


def open_reader(path: Path) -> tuple[IO[bytes], McapReader, Any]:
    """The file (the caller closes it), its MCAP reader (CRCs checked) and its summary (None when it has none)."""
    check_mcap(path)
    f = open(path, "rb")  # noqa: SIM115 - the caller closes it
    try:
        reader = make_reader(f, validate_crcs=True)  # a damaged chunk is an error, not bad data
        stat = os.fstat(f.fileno())
        summary = _summary(str(path), stat.st_mtime_ns, stat.st_size, reader)
    except Exception as exc:
        f.close()
        raise damaged(path, exc) from None
    for index in summary.chunk_indexes if summary is not None else ():
        if index.uncompressed_size > MAX_CHUNK_BYTES:
            f.close()
            raise inflates(path, index.chunk_start_offset, index.uncompressed_size)
    return f, reader, summary


MAX_CHUNK_BYTES = 64 << 20
"""A chunk that inflates past 64 MiB is refused before it is decompressed: hapticlab's are 128 KiB (one message
past that makes one larger, never by this much), and a small file can hold a chunk of gigabytes of zeros."""


def inflates(path: Path, offset: int, size: int) -> RecordingError:
    """The error for a chunk declaring ``size`` bytes uncompressed, past ``MAX_CHUNK_BYTES``."""
    return RecordingError(
        f"{path}: chunk at byte {offset} inflates to {size / 2**20:.0f} MiB "
        f"(at most {MAX_CHUNK_BYTES >> 20} MiB): not a recording hapticlab reads"
    )


_SUMMARIES: dict[tuple[str, int, int], Any] = {}


def _summary(path: str, mtime_ns: int, size: int, reader) -> Any:
    """The file's MCAP summary, parsed once per version of the file (a long session's has thousands of chunk
    indexes: a review opens the file several times)."""
    key = (path, mtime_ns, size)
    if key not in _SUMMARIES:
        if len(_SUMMARIES) >= 2:  # the file in hand (and the one before): a cohort's worker reads hundreds
            _SUMMARIES.clear()
        _SUMMARIES[key] = reader.get_summary()
    return _SUMMARIES[key]


_OFFSETS: dict[tuple[str, int, int], int] = {}


def log_offset(path: Path) -> int:
    """How far a message's log time in ``path`` is ahead of its time on the session clock, ns: the
    ``hapticlab.session`` record's ``clock_offset_ns`` (log times are Unix time), 0 without one (a file
    from before, or from another tool: log time is the time). Read once per version of the file, as
    the summary is; a value that is not an offset is a :class:`RecordingError`."""
    with contextlib.suppress(OSError):
        stat = os.stat(path)
        known = _OFFSETS.get((str(path), stat.st_mtime_ns, stat.st_size))
        if known is not None:
            return known
    f, reader, _ = open_reader(path)
    with f:
        stat = os.fstat(f.fileno())
        key = (str(path), stat.st_mtime_ns, stat.st_size)
        if key not in _OFFSETS:
            session: dict[str, str] = {}
            try:
                for record in reader.iter_metadata():
                    if record.name == SESSION_METADATA:
                        session.update(record.metadata)
            except Exception as exc:
                raise damaged(path, exc) from None
            try:
                offset = clock_offset(session)
            except ValueError as exc:
                raise RecordingError(f"{path}: metadata {SESSION_METADATA}, {exc}") from None
            if len(_OFFSETS) >= 2:  # as _SUMMARIES: the file in hand and the one before
                _OFFSETS.clear()
            _OFFSETS[key] = offset
        return _OFFSETS[key]


def block_kind(schema: Any, channel: Channel) -> Any:
    """None for a channel of single messages, ``"json"`` for JSON blocks (format 2), the
    :class:`~.cdr_layouts.CdrBlock` layout for CDR blocks (format 3)."""
    if schema is None:
        return None
    if channel.message_encoding == "cdr" and schema.encoding == "ros2msg":
        return CDR_BLOCK_SCHEMAS.get(schema.name)
    return "json" if schema.name in BLOCK_SCHEMA_TITLES else None


@dataclass(frozen=True)
class FileStats:
    """What a recording's MCAP summary says without reading its messages (:func:`file_stats`).

    Attributes:
        start_ns, end_ns: the first and last message's time, ns on the session clock (log time
            minus :func:`log_offset`).
        counts: messages per topic.
    """

    start_ns: int
    end_ns: int
    counts: dict[str, int]


def file_stats(path: str | os.PathLike[str]) -> FileStats:
    """The time span and message counts of a recording from its summary (a finished file: milliseconds)."""
    path = Path(path)
    f, _, summary = open_reader(path)
    with f:
        pass
    stats = summary.statistics if summary is not None else None
    if stats is None:
        raise RecordingError(f"{path}: no summary statistics (an unfinished file?); {recover_hint(path)}")
    counts: dict[str, int] = {}
    for channel_id, channel in summary.channels.items():
        counts[channel.topic] = counts.get(channel.topic, 0) + int(stats.channel_message_counts.get(channel_id, 0))
    offset = log_offset(path) if stats.message_count else 0
    return FileStats(int(stats.message_start_time) - offset, int(stats.message_end_time) - offset, counts)


def read_head(path: Path) -> tuple[dict[str, dict[str, str]], dict[str, dict[str, Any]], dict[str, int], set[str]]:
    """Metadata records, schemas by topic, message counts by topic and the block topics (from the summary)."""
    f, reader, summary = open_reader(path)
    with f:
        metadata: dict[str, dict[str, str]] = {}
        try:
            for record in reader.iter_metadata():
                metadata.setdefault(record.name, {}).update(record.metadata)
        except Exception as exc:
            raise damaged(path, exc) from None
        schemas: dict[str, dict[str, Any]] = {}
        if summary is not None:
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                if schema is not None and schema.encoding == "jsonschema":
                    with contextlib.suppress(ValueError):
                        schemas[channel.topic] = json_loads(schema.data)
    counts: dict[str, int] = {}
    block_topics: set[str] = set()
    if summary is not None:
        stats = summary.statistics.channel_message_counts if summary.statistics else {}
        for channel_id, channel in summary.channels.items():
            counts[channel.topic] = counts.get(channel.topic, 0) + int(stats.get(channel_id, 0))
            schema = summary.schemas.get(channel.schema_id)
            if block_kind(schema, channel) is not None:
                block_topics.add(channel.topic)
    return metadata, schemas, counts, block_topics
