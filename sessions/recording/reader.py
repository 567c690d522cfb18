"""Reading a recording: one :class:`Recording` shape, opened lazily or read into memory.

:func:`open_recording` reads the metadata and the channel list and decodes a
topic only when it is asked for (``messages(topic)`` streams it);
:func:`read_recording` reads every topic (or the given ones) at once;
:func:`iter_messages` streams ``(topic, t_ns, message)`` over several topics.
Messages are decoded by their channel's encoding (:data:`DECODERS`).

The three layouts (``schemas.FORMAT_VERSION``) read the same: a block message
of format 2 (a JSON channel whose schema is a block schema) or 3 (a ``cdr``
channel with a CDR block schema, :mod:`.cdr`) comes out as one ``(t_ns,
message)`` per sample, exactly the messages format 1 recorded one by one
(lists; ``params``/``cov_diag`` on the block's last sample, None on the
others; a non-finite float as None, as JSON's null); :meth:`Recording.field`,
:meth:`Recording.t_ns` and :meth:`Recording.estimates` concatenate a block
topic's arrays without building the per-sample messages (NaN for every
non-finite float, ±inf too, as formats 1 and 2 read their null).

A file that is not MCAP, or is truncated or damaged, is a :class:`RecordingError`
with one line that says what is wrong (and to run ``hapticlab recover``).
"""

from __future__ import annotations

import gc
import json
import os
import struct
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from dataclasses import field as _dc_field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Message

from hapticlab.core.errors import UserError
from hapticlab.core.types import Estimates, Event
from hapticlab.sessions.recording.cdr import CdrBlockError, decode_block, listed
from hapticlab.sessions.recording.schemas import (
    BLOCK_LAST_SAMPLE_FIELDS,
    BLOCK_SCHEMA_TITLES,
    BLOCK_TOPICS,
    CDR_BLOCK_SCHEMAS,
    ESTIMATOR_TOPIC_PREFIX,
    MCAP_MAGIC,
    SESSION_METADATA,
)


class RecordingError(UserError, ValueError):
    """A recording that cannot be read: not an MCAP file, truncated or corrupt."""


def _recover_hint(path: Path) -> str:
    return f"run `hapticlab recover {path} -o FIXED.mcap` to salvage it"


def _truncated(path: Path) -> RecordingError:
    return RecordingError(f"{path} is truncated (no MCAP footer; the writer probably died): {_recover_hint(path)}")


def _damaged(path: Path, exc: BaseException) -> RecordingError:
    detail = str(exc).replace("\n", " ") or type(exc).__name__
    return RecordingError(f"{path} is a damaged MCAP file ({detail}): {_recover_hint(path)}")


def _check_mcap(path: Path) -> None:
    """RecordingError unless ``path`` starts and ends with the MCAP magic and has a footer."""
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


DECODERS: dict[str, Any] = {"json": json.loads}
"""Message encoding (the MCAP channel's) -> function from the message bytes to a dict."""


@dataclass
class Recording:
    """A recording: its metadata, and its topics decoded (at once or on first use).

    Attributes:
        path: the file.
        metadata: metadata record name -> {key: string value} (records with the
            same name are merged, later keys win); :meth:`meta` decodes a value.
        topics: topic -> [(log_time_ns, decoded message)], in log-time order
            (with :func:`open_recording`, each topic is read on first access).
        schemas: topic -> its JSON schema (decoded).
        blocks: block topic (formats 2 and 3) -> its block messages in file order,
            as recorded (format 3: ``{field: numpy array}``, (n,) or (n, width);
            with :func:`open_recording`, read on first use).
    """

    path: Path
    metadata: dict[str, dict[str, str]]
    topics: Mapping[str, list[tuple[int, dict[str, Any]]]]
    schemas: dict[str, dict[str, Any]] = _dc_field(default_factory=dict)
    blocks: Mapping[str, list[dict[str, Any]]] = _dc_field(default_factory=dict)

    @property
    def format_version(self) -> int:
        """The layout the session was recorded in (``format_version`` of ``hapticlab.session``; 1 when absent)."""
        version = self.meta(SESSION_METADATA, "format_version", 1)
        return version if isinstance(version, int) else 1

    @property
    def topic_names(self) -> list[str]:
        """Topics with at least one message, sorted."""
        if isinstance(self.topics, _LazyTopics):
            return sorted(t for t, n in self.topics.counts.items() if n)
        return sorted(t for t, msgs in self.topics.items() if msgs)

    def __contains__(self, topic: object) -> bool:
        return topic in self.topic_names

    def _msgs(self, topic: str) -> list[tuple[int, dict[str, Any]]]:
        try:
            return self.topics[topic]
        except KeyError:
            present = ", ".join(self.topic_names)
            raise KeyError(f"topic {topic!r} is not in {self.path}; present: {present}") from None

    def messages(self, topic: str) -> Iterator[tuple[int, dict[str, Any]]]:
        """``(t_ns, message)`` of ``topic`` in time order, whatever the encoding (streamed when opened lazily)."""
        if isinstance(self.topics, _LazyTopics) and topic not in self.topics.loaded:
            if topic not in self.topics:
                self._msgs(topic)  # the KeyError naming the topics present
            return (item[1:] for item in iter_messages(self.path, topic))
        return iter(self._msgs(topic))

    @property
    def events(self) -> list[Event]:
        """Everything recorded on ``/events``, as Event records."""
        if "/events" not in self.topics:
            return []
        return [Event(t, m["kind"], m["message"], m.get("data") or {}) for t, m in self.messages("/events")]

    def wrench(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The raw sensor stream: (N,) t_ns, (N, 3) force_S (N), (N, 3) torque_S (N·m); NaN where not finite."""
        topic = "/sensor/wrench"
        return self.t_ns(topic), self.field(topic, "force_S"), self.field(topic, "torque_S")

    def poses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The kinematics stream: (M,) t_ns, (M, 4) quat_BE [w, x, y, z], (M, 3) p_BoEo_B (m) or None."""
        topic = "/kinematics/pose"
        p = self.field(topic, "p_BoEo_B")
        return self.t_ns(topic), self.field(topic, "quat_BE"), p if p.ndim == 2 else None

    def estimates(self, name: str) -> Estimates:
        """An estimator's recorded output (``/estimator/<name>``) as arrays; ``params`` from its last report."""
        topic = f"/estimator/{name}"
        blocks = self._blocks(topic)
        if blocks is not None:
            reports = [b["params"] for b in blocks if b.get("params")]
        else:
            reports = [m["params"] for _, m in self._msgs(topic) if m.get("params")]
        return Estimates(
            self.t_ns(topic),
            self.field(topic, "contact_force_S"),
            self.field(topic, "contact_torque_S"),
            self.field(topic, "contact").astype(bool),
            self.field(topic, "converged_force").astype(bool),
            self.field(topic, "converged_torque").astype(bool),
            params=reports[-1] if reports else None,
        )

    @property
    def estimator_names(self) -> list[str]:
        """The estimators recorded (the ``<name>`` of every ``/estimator/<name>`` topic)."""
        return sorted(t.removeprefix("/estimator/") for t in self.topics if t.startswith("/estimator/"))

    def t_ns(self, topic: str) -> np.ndarray:
        """(N,) int64 log times of ``topic``, ns."""
        blocks = self._blocks(topic)
        if blocks is not None:
            return _block_times(blocks)
        return np.fromiter((t for t, _ in self._msgs(topic)), dtype=np.int64, count=len(self._msgs(topic)))

    def t(self, topic: str) -> np.ndarray:
        """(N,) float seconds of ``topic`` since the first message of the recording."""
        return (self.t_ns(topic) - self.start_ns) * 1e-9

    def field(self, topic: str, name: str) -> np.ndarray:
        """Field ``name`` of every message on ``topic``, stacked: (N,) or (N, k).

        ``name`` may be a dotted path into nested objects (``"pose.quat_DH"``,
        ``"params.gravity_force_B"``). Numbers come back as float (null, i.e.
        non-finite or unknown, becomes NaN), flags as bool, integers as int64;
        ragged or non-numeric values as an object array.
        """
        blocks = self._blocks(topic)
        if blocks is not None and "." not in name and name not in BLOCK_LAST_SAMPLE_FIELDS:
            return self._block_field(topic, blocks, name)
        msgs = self._msgs(topic)
        keys = name.split(".")
        missing = object()
        values: list[Any] = []
        found = False
        for _, m in msgs:
            v: Any = m
            for k in keys:
                v = v.get(k, missing) if isinstance(v, dict) else missing
                if v is missing:
                    break
            if v is missing:
                values.append(None)  # an optional field absent from this message
            else:
                values.append(v)
                found = True
        if msgs and not found:
            raise KeyError(f"{topic} has no field {name!r}")
        return _stack(values)

    def _blocks(self, topic: str) -> list[dict[str, Any]] | None:
        """The block messages of ``topic`` when all of it is blocks whose samples are in time order, else None."""
        if topic not in self.topics:
            self._msgs(topic)  # the KeyError naming the topics present
        return self.blocks.get(topic)

    def _block_field(self, topic: str, blocks: list[dict[str, Any]], name: str) -> np.ndarray:
        if blocks and isinstance(blocks[0]["t_ns"], np.ndarray):
            return _cdr_block_field(topic, blocks, name)
        values: list[Any] = []
        found = False
        for b in blocks:
            column = b.get(name)
            if column is None:
                values.extend([None] * len(b["t_ns"]))  # an optional field absent from this block
            else:
                values.extend(column)
                found = True
        if blocks and not found:
            raise KeyError(f"{topic} has no field {name!r}")
        return _stack(values)

    def meta(self, record: str, key: str, default: Any = None) -> Any:
        """A metadata value, JSON-decoded when it is JSON (else the raw string)."""
        raw = self.metadata.get(record, {}).get(key)
        if raw is None:
            return default
        try:
            return json.loads(raw)
        except ValueError:
            return raw

    @property
    def start_ns(self) -> int:
        """Earliest log time of any message, ns (0 for an empty recording)."""
        starts = [msgs[0][0] for msgs in self.topics.values() if msgs]
        return min(starts) if starts else 0

    @property
    def end_ns(self) -> int:
        """Latest log time of any message, ns (0 for an empty recording)."""
        ends = [msgs[-1][0] for msgs in self.topics.values() if msgs]
        return max(ends) if ends else 0

    @property
    def duration(self) -> float:
        """Time from the first to the last message, s."""
        return (self.end_ns - self.start_ns) * 1e-9

    def __len__(self) -> int:
        return sum(len(m) for m in self.topics.values())


def _block_times(blocks: list[dict[str, Any]]) -> np.ndarray:
    if blocks and isinstance(blocks[0]["t_ns"], np.ndarray):
        return np.concatenate([b["t_ns"] for b in blocks]).astype(np.int64, copy=False)
    times = [t for b in blocks for t in b["t_ns"]]
    return np.fromiter(times, dtype=np.int64, count=len(times))


def _cdr_block_field(topic: str, blocks: list[dict[str, Any]], name: str) -> np.ndarray:
    """A field of CDR blocks concatenated: the recorded dtype (int64, bool, float with NaN for every
    non-finite value); float with NaN where a block lacks the field (as ``_stack`` does for JSON)."""
    parts = [b.get(name) for b in blocks]
    present = [p for p in parts if p is not None]
    if not present:
        raise KeyError(f"{topic} has no field {name!r}")
    if len(present) < len(parts):
        shape = present[0].shape[1:]
        parts = [
            np.full((len(b["t_ns"]), *shape), np.nan) if p is None else p.astype(float) for b, p in zip(blocks, parts)
        ]
    out = np.concatenate(parts)
    if out.dtype.kind == "f":
        bad = ~np.isfinite(out)
        if bad.any():
            out[bad] = np.nan  # ±inf too: formats 1 and 2 recorded every non-finite float as null
    elif out.dtype.kind == "i":
        out = out.astype(np.int64, copy=False)
    return out


def _check_block(path: Path, topic: str, log_time: int, block: Any) -> None:
    """RecordingError unless ``block`` is a block message: ``t_ns`` integers and every other array as long."""
    where = f"{path.name}: {topic} block message at {log_time} ns"
    if not isinstance(block, dict):
        raise RecordingError(f"{where} is not a JSON object")
    t_ns = block.get("t_ns")
    if not isinstance(t_ns, list) or not t_ns or not all(type(t) is int for t in t_ns):
        raise RecordingError(f"{where}: t_ns is not a non-empty list of integer times")
    n = len(t_ns)
    for key, column in block.items():
        if key not in BLOCK_LAST_SAMPLE_FIELDS and (not isinstance(column, list) or len(column) != n):
            raise RecordingError(f"{where}: field {key!r} does not hold one value for each of its {n} samples")


def _expand(topic: str, block: dict[str, Any]) -> list[tuple[int, dict[str, Any]]]:
    """A (checked) block message as its samples' ``(t_ns, message)``, the messages format 1 recorded:
    on an estimator topic every sample has ``params``/``cov_diag``, the block's on the last, None before.
    Arrays of a CDR block become lists (a non-finite float None, as JSON's null)."""
    t_ns = block["t_ns"]
    columns = [(k, v) for k, v in block.items() if k != "t_ns" and k not in BLOCK_LAST_SAMPLE_FIELDS]
    if isinstance(t_ns, np.ndarray):
        t_ns = t_ns.tolist()
        columns = [(k, listed(v)) for k, v in columns]
    out = [(t, {k: v[i] for k, v in columns}) for i, t in enumerate(t_ns)]
    if topic.startswith(ESTIMATOR_TOPIC_PREFIX):
        for _, m in out:
            m.update(dict.fromkeys(BLOCK_LAST_SAMPLE_FIELDS))
        out[-1][1].update((k, block.get(k)) for k in BLOCK_LAST_SAMPLE_FIELDS)
    return out


def _stack(values: list[Any]) -> np.ndarray:
    n = len(values)
    if n == 0:
        return np.empty(0)
    present = [v for v in values if v is not None]
    if not present:
        return np.full(n, np.nan)
    if all(isinstance(v, bool) for v in present) and len(present) == n:
        return np.array(values, dtype=bool)
    if len(present) < n:
        template = present[0]
        fill: Any = [None] * len(template) if isinstance(template, list) else None
        values = [fill if v is None else v for v in values]
    try:
        arr = np.asarray(values)
    except ValueError:  # ragged
        arr = np.empty(n, dtype=object)
        arr[:] = values
        return arr
    if arr.dtype == object or len(present) < n:
        try:
            return np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            return arr
    return arr


def _open_reader(path: Path):  # noqa: ANN202 - returns (file, reader)
    _check_mcap(path)
    f = open(path, "rb")  # noqa: SIM115 - the caller closes it
    try:
        reader = make_reader(f, validate_crcs=True)  # a damaged chunk is an error, not bad data
        stat = os.fstat(f.fileno())
        summary = _summary(str(path), stat.st_mtime_ns, stat.st_size, reader)
    except Exception as exc:
        f.close()
        raise _damaged(path, exc) from None
    return f, reader, summary


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


def _block_kind(schema: Any, channel: Channel) -> Any:
    """None for a channel of single messages, ``"json"`` for JSON blocks (format 2), the
    :class:`~.schemas.CdrBlock` layout for CDR blocks (format 3)."""
    if schema is None:
        return None
    if channel.message_encoding == "cdr" and schema.encoding == "ros2msg":
        return CDR_BLOCK_SCHEMAS.get(schema.name)
    return "json" if schema.name in BLOCK_SCHEMA_TITLES else None


def _iter_raw(
    path: Path, topics: Iterable[str] | str | None, log_time_order: bool = True
) -> Iterator[tuple[Any, Channel, Message]]:
    """``(block kind (see _block_kind), channel, message)`` of ``topics`` (all when None)."""
    f, reader, _ = _open_reader(path)
    with f:
        topic_list = [topics] if isinstance(topics, str) else (list(topics) if topics is not None else None)
        try:
            for schema, channel, message in reader.iter_messages(topics=topic_list, log_time_order=log_time_order):
                yield _block_kind(schema, channel), channel, message
        except (McapError, struct.error, EOFError, ValueError, KeyError) as exc:
            raise _damaged(path, exc) from None
        except Exception as exc:  # zstd errors and the like
            if type(exc).__module__.startswith(("zstandard", "mcap")):
                raise _damaged(path, exc) from None
            raise


def iter_messages(
    path: str | os.PathLike[str], topics: Iterable[str] | str | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """Stream ``(topic, t_ns, message)`` in log-time order without loading the file.

    ``topics`` limits the topics read (chunks without them are skipped). A
    block message (format 2) comes out as one message per sample, each at its
    own time (blocks are in log-time order, the last sample's time).
    Raises :class:`RecordingError` for a file that is not MCAP or is truncated.
    """
    path = Path(path)
    _check_mcap(path)  # fail here, not at the first next()
    return _expanded(_decode(_iter_raw(path, topics), path), path)


def iter_blocks(
    path: str | os.PathLike[str], topics: Iterable[str] | str | None = None
) -> Iterator[tuple[str, int, dict[str, Any], bool]]:
    """Stream ``(topic, log time ns, message, is a block)`` in file order, blocks kept whole.

    The fast way through a long file: a block message (formats 2 and 3) comes
    out once, columnar (``{"t_ns": (n,) int64, field: (n,) or (n, k) array}``;
    a non-finite float NaN (JSON's null) or as recorded (CDR: NaN or ±inf), a field
    absent from a JSON block NaN); a format-1 message on
    a sensor-rate topic comes out as a one-sample block; any other message as
    decoded. File order is the order the session wrote them: each tick's
    wrench, aligned and estimator messages together, in that order.
    Raises :class:`RecordingError` for a file that is not MCAP or is truncated.
    """
    path = Path(path)
    _check_mcap(path)
    for block, topic, t_ns, message in _decode(_iter_raw(path, topics, log_time_order=False), path):
        if block:
            yield topic, t_ns, _columns(message), True
        elif topic in BLOCK_TOPICS or topic.startswith(ESTIMATOR_TOPIC_PREFIX):
            yield (
                topic,
                t_ns,
                _columns(
                    {
                        "t_ns": [t_ns],
                        **{k: [v] for k, v in message.items() if k not in BLOCK_LAST_SAMPLE_FIELDS},
                        **{k: message.get(k) for k in BLOCK_LAST_SAMPLE_FIELDS},
                    }
                ),
                True,
            )
        else:
            yield topic, t_ns, message, False


def _columns(block: dict[str, Any]) -> dict[str, Any]:
    """A block message with every per-sample column as a numpy array (JSON lists stacked, null → NaN)."""
    out: dict[str, Any] = {}
    for key, column in block.items():
        if key in BLOCK_LAST_SAMPLE_FIELDS:
            out[key] = column
        elif isinstance(column, np.ndarray):  # CDR: as recorded (a non-finite float NaN or ±inf)
            out[key] = column
        else:
            out[key] = np.asarray(column, dtype=np.int64) if key == "t_ns" else _stack(column)
    return out


def _decoder(path: Path, channel: Channel):
    try:
        return DECODERS[channel.message_encoding]
    except KeyError:
        raise RecordingError(
            f"{path}: topic {channel.topic} has message encoding "
            f"{channel.message_encoding!r}; hapticlab reads {', '.join(DECODERS)}"
        ) from None


def _decode(raw: Iterator[tuple[Any, Channel, Message]], path: Path) -> Iterator[tuple[bool, str, int, dict[str, Any]]]:
    """``(is a block, topic, log time, decoded message)``; a block message is checked."""
    decoders: dict[int, Any] = {}
    for block, channel, message in raw:
        if block is None or block == "json":
            decode = decoders.get(channel.id) or decoders.setdefault(channel.id, _decoder(path, channel))
            decoded = decode(message.data)
            if block:
                _check_block(path, channel.topic, message.log_time, decoded)
        else:
            try:
                decoded = decode_block(block, message.data, json.loads)
            except (CdrBlockError, UnicodeDecodeError, ValueError) as exc:
                raise RecordingError(
                    f"{path.name}: {channel.topic} block message at {message.log_time} ns: {exc}"
                ) from None
        yield block is not None, channel.topic, message.log_time, decoded


def _expanded(
    decoded: Iterator[tuple[bool, str, int, dict[str, Any]]], path: Path
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    for block, topic, t_ns, message in decoded:
        if block:
            for t, m in _expand(topic, message):
                yield topic, t, m
        else:
            yield topic, t_ns, message


class _LazyBlocks(Mapping):
    """block topic -> its block messages, read from the file the first time (via :class:`_LazyTopics`)."""

    def __init__(self, topics: _LazyTopics):
        self.topics = topics

    def __getitem__(self, topic: str) -> list[dict[str, Any]]:
        blocks = self.topics.block_messages(topic)
        if blocks is None:
            raise KeyError(topic)
        return blocks

    def __iter__(self):
        return (t for t in sorted(self.topics.block_topics) if self.topics.block_messages(t) is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class _LazyTopics(Mapping):
    """topic -> [(t_ns, message)], each topic read from the file the first time it is asked for."""

    def __init__(self, path: Path, counts: dict[str, int], block_topics: set[str]):
        self.path, self.counts, self.block_topics = path, counts, block_topics
        self.loaded: dict[str, list[tuple[int, dict[str, Any]]]] = {}
        self.blocks: dict[str, list[dict[str, Any]] | None] = {}

    def block_messages(self, topic: str) -> list[dict[str, Any]] | None:
        """The topic's block messages (read once) when it is all blocks in time order, else None."""
        if topic not in self.block_topics:
            return None
        if topic not in self.blocks:
            self.blocks[topic] = _read_topics(self.path, [topic], expand=False)[1].get(topic)
        return self.blocks[topic]

    def __getitem__(self, topic: str) -> list[tuple[int, dict[str, Any]]]:
        if topic not in self.counts:
            raise KeyError(topic)
        if topic not in self.loaded:
            blocks = self.block_messages(topic)
            if blocks is not None:
                self.loaded[topic] = [item for b in blocks for item in _expand(topic, b)]
            else:
                self.loaded[topic] = _read_topics(self.path, [topic])[0].get(topic, [])
        return self.loaded[topic]

    def __iter__(self):
        return iter(self.counts)

    def __len__(self) -> int:
        return len(self.counts)


@dataclass(frozen=True)
class FileStats:
    """What a recording's MCAP summary says without reading its messages (:func:`file_stats`).

    Attributes:
        start_ns, end_ns: the first and last message's log time, ns.
        counts: messages per topic.
    """

    start_ns: int
    end_ns: int
    counts: dict[str, int]


def file_stats(path: str | os.PathLike[str]) -> FileStats:
    """The time span and message counts of a recording from its summary (a finished file: milliseconds)."""
    path = Path(path)
    f, _, summary = _open_reader(path)
    with f:
        pass
    stats = summary.statistics if summary is not None else None
    if stats is None:
        raise RecordingError(f"{path}: no summary statistics (an unfinished file?); {_recover_hint(path)}")
    counts: dict[str, int] = {}
    for channel_id, channel in summary.channels.items():
        counts[channel.topic] = counts.get(channel.topic, 0) + int(stats.channel_message_counts.get(channel_id, 0))
    return FileStats(int(stats.message_start_time), int(stats.message_end_time), counts)


def open_recording(path: str | os.PathLike[str]) -> Recording:
    """Open a recording: metadata and topics now, each topic's messages when first asked for.

    Raises :class:`RecordingError` with one line when the file is not MCAP, or
    is truncated or damaged (the message says to run ``hapticlab recover``).
    """
    path = Path(path)
    metadata, schemas, counts, block_topics = _read_head(path)
    topics = _LazyTopics(path, counts, block_topics)
    return Recording(path=path, metadata=metadata, topics=topics, schemas=schemas, blocks=_LazyBlocks(topics))


def read_recording(path: str | os.PathLike[str], topics: Iterable[str] | str | None = None) -> Recording:
    """Read a recording into memory (optionally only some ``topics``).

    Raises :class:`RecordingError` (a ``ValueError``) with a one-line message
    when the file is not MCAP, or is truncated or damaged (the message says to
    run ``hapticlab recover``).
    """
    path = Path(path)
    metadata, schemas, _, _ = _read_head(path)
    samples, blocks = _read_topics(path, topics)
    return Recording(path=path, metadata=metadata, topics=samples, schemas=schemas, blocks=blocks)


def _read_head(path: Path) -> tuple[dict[str, dict[str, str]], dict[str, dict[str, Any]], dict[str, int], set[str]]:
    """Metadata records, schemas by topic, message counts by topic and the block topics (from the summary)."""
    f, reader, summary = _open_reader(path)
    with f:
        metadata: dict[str, dict[str, str]] = {}
        try:
            for record in reader.iter_metadata():
                metadata.setdefault(record.name, {}).update(record.metadata)
        except Exception as exc:
            raise _damaged(path, exc) from None
        schemas: dict[str, dict[str, Any]] = {}
        if summary is not None:
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                if schema is not None and schema.encoding == "jsonschema":
                    try:
                        schemas[channel.topic] = json.loads(schema.data)
                    except ValueError:
                        pass
    counts: dict[str, int] = {}
    block_topics: set[str] = set()
    if summary is not None:
        stats = summary.statistics.channel_message_counts if summary.statistics else {}
        for channel_id, channel in summary.channels.items():
            counts[channel.topic] = counts.get(channel.topic, 0) + int(stats.get(channel_id, 0))
            schema = summary.schemas.get(channel.schema_id)
            if _block_kind(schema, channel) is not None:
                block_topics.add(channel.topic)
    return metadata, schemas, counts, block_topics


def _read_topics(
    path: Path, topics: Iterable[str] | str | None, expand: bool = True
) -> tuple[dict[str, list[tuple[int, dict[str, Any]]]], dict[str, list[dict[str, Any]]]]:
    """Every sample of ``topics`` as ``(t_ns, message)`` in time order (block messages left out unless
    ``expand``), and the block messages of the topics that are all blocks with their samples in time
    order (the fast path of ``field``)."""
    out: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    blocks: dict[str, list[dict[str, Any]]] = {}
    per_sample: set[str] = set()  # topics with messages of the per-sample layout
    # File order (no global time-ordered merge, which costs more than the decoding), with the
    # cyclic GC paused while building many small containers; each topic is sorted afterwards.
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for block, topic, t_ns, message in _decode(_iter_raw(path, topics, log_time_order=False), path):
            if block:
                blocks.setdefault(topic, []).append(message)
                if expand:
                    out.setdefault(topic, []).extend(_expand(topic, message))
            else:
                per_sample.add(topic)
                out.setdefault(topic, []).append((t_ns, message))
    finally:
        if gc_was_enabled:
            gc.enable()
    for lst in out.values():
        if any(lst[i][0] > lst[i + 1][0] for i in range(len(lst) - 1)):
            lst.sort(key=lambda item: item[0])  # stable: equal times keep file order
    for topic in list(blocks):
        t = _block_times(blocks[topic])
        if topic in per_sample or bool((np.diff(t) < 0).any()):
            del blocks[topic]  # not all blocks, or the blocks' order is not the samples'
    return out, blocks
