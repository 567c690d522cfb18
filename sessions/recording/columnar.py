"""A recording's chunks as columns: the fast way through a long file (a review of a 15-minute session).

A session writes a block message per hand-over on each sensor-rate topic and a
JSON message per tick on the others: a long session holds millions of
messages, and the ``mcap`` reader's Python work per message plus a CDR decode
per block make a pass over it take minutes (docs/review.md, "How it reads a
long file"). :func:`iter_chunks` reads the file a chunk at a time instead:

* consecutive chunks are decompressed once each (zstd or lz4, CRC checked)
  and read together, up to :data:`GROUP_BYTES`; their messages of the topics
  asked for are found from the chunks' message indexes (arrays of offsets,
  read with numpy: no Python work per message);
* the CDR blocks of a topic are gathered into a 2-D byte array per message
  length and each field is read for all of them at once (one layout per
  length: every block of one length has the same sample count; a block
  carrying an estimator's ``params`` is decoded alone);
* the JSON messages of a topic are parsed with one ``json.loads`` per chunk.

What it yields per group of chunks, per topic asked: for a CDR block topic the chunk's
samples as columns (``t_ns`` and every field present, rows in time order) with
``params`` as ``[(t_ns of the block's last sample, params)]``; for any other
topic ``[(t_ns, message)]``, the log time on the session clock (as every reader
gives it: minus :func:`~.mcapfile.log_offset`). Files whose blocks are JSON (format 2) or
that have no chunk index (unfinished) are not for this reader
(:func:`can_read`): :func:`~.messages.iter_blocks` reads every format.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hapticlab.sessions.recording.cdr import CdrBlockError, block_layout, decode_block
from hapticlab.sessions.recording.mcapfile import (
    MAX_CHUNK_BYTES,
    RecordingError,
    block_kind,
    inflates,
    json_loads,
    log_offset,
    open_reader,
)

if TYPE_CHECKING:
    from mcap.records import ChunkIndex

_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, record length, start, end, uncompressed size, crc, compression len
_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel id, records length
MESSAGE_HEADER = 1 + 8 + 2 + 4 + 8 + 8
"""Bytes before a message's data in its record: opcode, length, channel id, sequence, log and publish time."""


def can_read(path: str | os.PathLike[str]) -> bool:
    """The file is finished (chunk indexes in its summary, each chunk's message indexes written) and every
    block channel is CDR (format 3)."""
    f, _, summary = open_reader(Path(path))
    with f:
        pass
    if summary is None or not summary.chunk_indexes:
        return False
    if not all(index.message_index_offsets for index in summary.chunk_indexes):
        return False  # a writer that left out the message indexes (MCAP allows it): no offsets to read by
    kinds = [block_kind(summary.schemas.get(c.schema_id), c) for c in summary.channels.values()]
    return all(k is None or not isinstance(k, str) for k in kinds)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)  # no more than declared
    if compression == "":
        return data
    raise RecordingError(f"chunk compression {compression!r} is not one hapticlab reads")


GROUP_BYTES = 4 << 20
"""Consecutive chunks read together, up to this many uncompressed bytes (a session's chunks are 128 KiB:
the work per topic is paid per group, not per chunk; memory stays a few times this)."""


def _chunk_data(f, path: Path, index) -> bytes:
    """A chunk's records, decompressed and CRC-checked; RecordingError naming the chunk when damaged."""
    f.seek(index.chunk_start_offset)
    record = f.read(index.chunk_length)
    try:
        _, _, _, _, size, crc, _ = _CHUNK_HEAD.unpack_from(record)
        if size > MAX_CHUNK_BYTES:  # the chunk's own head, which the index need not agree with
            raise inflates(path, index.chunk_start_offset, size)
        data = _decompress(index.compression, record[-index.compressed_size :], size)
    except RecordingError:
        raise
    except Exception as exc:
        raise RecordingError(
            f"{path}: chunk at byte {index.chunk_start_offset} is damaged ({exc}); "
            f"run `hapticlab recover {path} -o FIXED.mcap`"
        ) from None
    if crc and zlib.crc32(data) != crc:
        raise RecordingError(
            f"{path}: chunk at byte {index.chunk_start_offset} fails its CRC; "
            f"run `hapticlab recover {path} -o FIXED.mcap`"
        )
    return data


def _index_pairs(f, offset: int) -> np.ndarray:
    """A message index record's (log time, offset) pairs, (k, 2) int64."""
    f.seek(offset)
    _, _, _, length = _INDEX_HEAD.unpack(f.read(_INDEX_HEAD.size))
    return np.frombuffer(f.read(length), dtype="<u8").reshape(-1, 2).astype(np.int64)


def iter_chunks(
    path: str | os.PathLike[str], topics: Iterable[str], json_fields: dict[str, dict[str, int]] | None = None
) -> Iterator[dict[str, Any]]:
    """Per group of consecutive chunks (up to :data:`GROUP_BYTES`), in file order: ``{topic: columns or
    [(t_ns, message)]}`` for the ``topics`` in it (see above).

    ``json_fields`` asks for a JSON topic as columns too: ``{topic: {field: width}}`` (width 0: a
    boolean; ``NUMBER``: one number; ``TEXT``: a string; else an array of that many numbers; null read as
    NaN; a key is found at a message's top level or in an object in it), e.g. ``{"/haptic/command":
    {"force_D": 3, "enabled": 0}}``: ``{"t_ns", field...}`` arrays, the messages never decoded one by
    one (a chunk whose messages do not all have the fields so is decoded and picked from)."""
    json_fields = json_fields or {}
    path = Path(path)
    wanted = set(topics)
    clock_offset = log_offset(path)  # the chunks' message indexes hold log times: Unix time in a recent file
    f, _, summary = open_reader(path)
    with f:
        channels = {cid: c for cid, c in summary.channels.items() if c.topic in wanted}
        kinds = {cid: block_kind(summary.schemas.get(c.schema_id), c) for cid, c in channels.items()}
        indexes = [
            i
            for i in sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset)
            if any(cid in channels for cid in i.message_index_offsets)
        ]
        while indexes:
            group: list[ChunkIndex] = []
            size = 0
            while indexes and (not group or size + indexes[0].uncompressed_size <= GROUP_BYTES):
                size += indexes[0].uncompressed_size
                group.append(indexes.pop(0))
            parts: list[bytes] = []
            pairs: dict[int, list[np.ndarray]] = {}  # channel id: its (log time, offset) pairs in each chunk
            base = 0
            for index in group:
                data = _chunk_data(f, path, index)
                for cid, offset in index.message_index_offsets.items():
                    if cid in channels:
                        found = _index_pairs(f, offset)
                        found[:, 1] += base
                        pairs.setdefault(cid, []).append(found)
                parts.append(data)
                base += len(data)
            data = b"".join(parts)
            buf = np.frombuffer(data, dtype=np.uint8)
            out: dict[str, Any] = {}
            for cid, per_chunk in pairs.items():
                both = np.concatenate(per_chunk)
                both = both[np.argsort(both[:, 1], kind="stable")]  # file order
                both[:, 0] -= clock_offset  # the session clock
                topic = channels[cid].topic
                try:
                    out[topic] = _messages(data, buf, both[:, 0], both[:, 1], kinds[cid], json_fields.get(topic))
                except (CdrBlockError, ValueError) as exc:
                    raise RecordingError(
                        f"{path.name}: {topic} in the chunks from byte {group[0].chunk_start_offset}: {exc}"
                    ) from None
            yield out


NUMBER = -1
"""A ``json_fields`` width: the field is one number (null read as NaN)."""
TEXT = -2
"""A ``json_fields`` width: the field is a string (an object array of ``str``)."""


def _field(message: dict[str, Any], name: str) -> Any:
    """``name`` of a decoded message, at its top level or in an object inside it (as the keys are found in the
    text: ``p_BoEo_B`` of ``/robot/target``'s ``pose``); None when absent."""
    if name in message:
        return message[name]
    return next((v[name] for v in message.values() if isinstance(v, dict) and name in v), None)


def picked(messages: list[dict[str, Any]], log_times: np.ndarray, fields: dict[str, int]) -> dict[str, np.ndarray]:
    """``fields`` of decoded JSON messages as columns (a missing or null value NaN, a missing flag False)."""
    out = {"t_ns": log_times}
    for name, width in fields.items():
        values = [_field(m, name) for m in messages]
        if width == 0:
            out[name] = np.array([bool(v) for v in values], dtype=bool)
        elif width == NUMBER:
            out[name] = np.array([math.nan if v is None else v for v in values], dtype=float)
        elif width == TEXT:
            out[name] = np.array(["" if v is None else str(v) for v in values], dtype=object)
        else:
            out[name] = np.array(
                [[math.nan if x is None else x for x in (v or [None] * width)] for v in values], dtype=float
            ).reshape(len(messages), width)
    return out


def _gather(buf: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(k, width) bytes: ``width`` bytes from each of ``starts``."""
    return buf[starts[:, None] + np.arange(width)]


def _json_columns(text: bytes, log_times: np.ndarray, fields: dict[str, int]) -> dict[str, np.ndarray] | None:
    """The ``fields`` of a chunk's JSON messages (joined in ``text``) as columns, found by their keys; None
    unless every message has each exactly once with the width asked (then the caller decodes them).
    A key's quoted name cannot occur inside a JSON string value (its quotes would be escaped)."""
    n = len(log_times)
    out = {"t_ns": log_times}
    for name, width in fields.items():
        key = re.escape(json.dumps(name).encode()) + rb"\s*:\s*"
        if width == 0:
            found = re.findall(key + rb"(true|false)", text)
            if len(found) != n:
                return None
            out[name] = np.array(found) == b"true"
            continue
        if width == TEXT:
            found = re.findall(key + rb'"((?:[^"\\]|\\.)*)"', text)
            if len(found) != n:
                return None
            out[name] = np.array(
                [json.loads(b'"' + v + b'"') if b"\\" in v else v.decode() for v in found], dtype=object
            )
            continue
        if width == NUMBER:
            found = re.findall(key + rb"(-?[0-9][0-9.eE+-]*|null)\s*[,}]", text)
            if len(found) != n:
                return None
            out[name] = np.array([b"nan" if v == b"null" else v for v in found], dtype="S").astype(float)
            continue
        found = re.findall(key + rb"\[([^\]]*)\]", text)
        if len(found) != n:
            return None
        numbers = b",".join(found).replace(b"null", b"nan").split(b",")
        if len(numbers) != n * width:
            return None
        out[name] = np.array(numbers, dtype="S").astype(float).reshape(n, width)
    return out


def _messages(
    data: bytes,
    buf: np.ndarray,
    log_times: np.ndarray,
    offsets: np.ndarray,
    kind: Any,
    json_fields: dict[str, int] | None = None,
):
    lengths = _gather(buf, offsets + 1, 8).copy().view("<u8").ravel().astype(np.int64)
    sizes = lengths - (MESSAGE_HEADER - 9)
    starts = offsets + MESSAGE_HEADER
    if kind is None:  # JSON messages: one parse for the chunk
        text = b"[" + b",".join(data[s : s + n] for s, n in zip(starts.tolist(), sizes.tolist())) + b"]"
        if json_fields:
            columns = _json_columns(text, log_times, json_fields)
            if columns is not None:
                return columns
            return picked(json_loads(text), log_times, json_fields)
        return list(zip(log_times.tolist(), json_loads(text)))
    groups: list[dict[str, np.ndarray]] = []  # each: (rows, width) columns of some of the blocks
    params: list[tuple[int, Any]] = []
    for size in np.unique(sizes).tolist():
        rows = np.flatnonzero(sizes == size)
        layout = block_layout(kind, data[starts[rows[0]] : starts[rows[0]] + size])
        block = _gather(buf, starts[rows], size)
        same = np.ones(len(rows), dtype=bool)
        for pos in layout.count_positions:  # the same sequence counts: the same layout
            same &= (block[:, pos : pos + 4] == block[0, pos : pos + 4]).all(axis=1)
        if layout.reports:
            same[:] = False  # a block with its estimator's params: decoded alone (one in a hundred)
        for r in rows[~same].tolist():
            one = decode_block(kind, data[starts[r] : starts[r] + size], json_loads)
            if "params" in one:
                params.append((int(one["t_ns"][-1]), one["params"]))
            groups.append(
                {k: v.reshape(len(one["t_ns"]), -1) for k, v in one.items() if k not in ("params", "cov_diag")}
            )
        if same.any():
            batch = block[same]
            groups.append(
                {
                    name: batch[:, start : start + nbytes].copy().view(dtype).reshape(-1, width)
                    for name, start, nbytes, dtype, width in layout.fields
                }
            )
    widths = {name: (arr.shape[1], arr.dtype) for g in groups for name, arr in g.items()}
    out: dict[str, Any] = {}  # the columns, then params
    for name, (width, _dtype) in widths.items():  # a field absent from some blocks: NaN there
        out[name] = np.concatenate([g[name] if name in g else np.full((len(g["t_ns"]), width), np.nan) for g in groups])
    order = np.argsort(out["t_ns"].ravel(), kind="stable")  # the groups back in time order
    out = {name: (arr[order].ravel() if arr.shape[1] == 1 else arr[order]) for name, arr in out.items()}
    out["params"] = sorted(params, key=lambda p: p[0])
    return out
