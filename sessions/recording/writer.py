"""Writing a session to one MCAP file (:class:`Recorder`).

One ``mcap`` writer per session, zstd-compressed chunks, JSON messages on
JSON-schema channels (viewable in Foxglove). The chunk in progress is finished
and flushed to the OS about once a second (``time.monotonic``) and on close,
so a crash of the process loses at most the last second;
:func:`~.recover.recover` salvages the rest of a file whose writer died. Log
time and publish time of a message are Unix time: its ``t_ns`` (integer ns on
the session's monotonic clock, as every caller gives it and every payload
holds it) plus the session's ``clock_offset_ns``, read once at the start, so
Foxglove shows real dates; the readers subtract it again.

The Recorder encodes (and checks) every message where it is written; the
``mcap`` writer runs in this process (``writer="inline"``) or in a child
process fed one batch per :meth:`Recorder.send` (``writer="process"``, what a
live session uses: the writing and the chunks' compression move to the other
core, and a killed session's file is finished by the child; see
:mod:`.process_sink` and :mod:`.sinks`).

Two ways in: :meth:`Recorder.write_block` writes a block of samples as one
columnar message on a sensor-rate topic (what a live session does: ``mcap``'s
writer costs the same per message whatever its size, and the sensor-rate
topics have thousands of samples a second), :meth:`Recorder.write` one JSON
message (per tick, per event, or one sample on a channel of the per-sample
layout, format 1). A topic's first message decides its channel's layout.

Blocks are CDR (format 3, the default: ROS 2 message definitions, schema
encoding ``ros2msg``, message encoding ``cdr``, see :mod:`.cdr`; a field costs
one ``tobytes``, with no formatting per value) or, with
``block_encoding="json"``, format 2's JSON blocks (kept to write files of that
layout, e.g. to compare with). The figures behind these choices are in
docs/safety.md, "Overruns".

Non-finite floats (NaN, ±inf) are not valid JSON; in JSON messages they are
recorded as ``null`` (and read back as NaN). CDR blocks hold them as they are;
the reader gives NaN for them all the same (as for every layout).

Metadata (MCAP Metadata records, string values; non-string values given by the
caller are JSON-encoded, :mod:`.metadata`): ``hapticlab.session`` (resolved
config, plugins, hapticlab version, git revision where known, start time,
``format_version``), ``hapticlab.calibration`` (whatever the caller gives),
``hapticlab.summary`` at close when given, and ``hapticlab.recovered`` in files
written by :func:`~.recover.recover`.
"""

from __future__ import annotations

import json
import operator
import os
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import orjson

from hapticlab.core.errors import OutputExistsError
from hapticlab.core.version import __version__
from hapticlab.sessions.recording.cdr import encode_block
from hapticlab.sessions.recording.cdr_layouts import cdr_block_for_topic
from hapticlab.sessions.recording.metadata import (
    clock_offset,
    json_default,
    metadata_strings,
    session_record,
    utc_now_iso,
    wall_clock_offset,
)
from hapticlab.sessions.recording.process_sink import ProcessSink
from hapticlab.sessions.recording.schemas import (
    FORMAT_VERSION,
    SESSION_METADATA,
    SUMMARY_METADATA,
    block_schema_for_topic,
    schema_for_topic,
)
from hapticlab.sessions.recording.sinks import McapSink, Sink

_MESSAGE_OPTIONS = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


def _encode(value: Any) -> bytes:
    """A message as compact JSON bytes (``orjson``: several times faster than ``json``'s encoder on the
    per-tick messages). Non-finite floats become ``null`` (JSON has no NaN); numpy arrays and scalars are
    written as their values. ``TypeError`` for what JSON cannot hold."""
    return orjson.dumps(value, default=json_default, option=_MESSAGE_OPTIONS)


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------

_U64 = 1 << 64


class Recorder:
    """Write one session to one MCAP file.

    Args:
        path: output ``.mcap`` file. Parent folders are created.
        metadata: metadata records to write at the start, ``{record name: {key: value}}``;
            values that are not strings are JSON-encoded. The ``hapticlab.session``
            record is always written; ``format_version`` (the layout :meth:`write_block`
            writes: :data:`~.schemas.FORMAT_VERSION`, 2 with ``block_encoding="json"``),
            ``hapticlab_version``, ``git_revision``
            (where known), ``start_time`` (UTC, ISO 8601), ``start_monotonic_ns`` (the session
            clock at that instant), ``python`` and ``mcap`` are filled in unless given;
            ``clock_offset_ns`` (Unix time minus the session clock, ns, what every log time
            adds to its ``t_ns``) is read from the clocks at the start unless given (a copy
            of another recording keeps that one's, so its log times stay its dates).
            Put the resolved config under ``config`` and plugin names/versions under
            ``plugins``; put counts per unit etc. in ``hapticlab.calibration``.
        flush_interval_s: finish the chunk in progress and flush it to the OS when
            this much ``time.monotonic`` time has passed since the last flush (checked
            on each write). A crash loses at most this much data.
        chunk_size: uncompressed bytes after which a chunk is finished early (default 128 KiB). The
            write that finishes a chunk pays for its zstd compression, so smaller chunks mean
            smaller latency spikes, at a slightly worse compression.
        overwrite: replace an existing file; by default an existing file is an
            error (a previous recording is never silently destroyed).
        block_encoding: ``"cdr"`` (format 3) or ``"json"`` (format 2): how
            :meth:`write_block` encodes its blocks.
        writer: ``"inline"`` (the ``mcap`` writer in this process) or ``"process"``
            (in a child process: messages are handed over at each :meth:`send`, one
            pipe write per loop tick; the child finishes the file if this process dies).
        live: ``"HOST:PORT"``: the writer process also serves every message live over
            Foxglove's WebSocket protocol there (``foxglove-sdk``; port 0 picks a free one,
            :attr:`live_address` says which); "" (default) no live view.

    ``write_block`` (a block of samples, per loop tick) and ``write`` (one
    message) are the hot path: one encode (CDR: one ``tobytes`` per field;
    JSON), one dict lookup, one ``mcap`` add each. Both are thread-safe.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Mapping[str, Any]] | None = None,
        flush_interval_s: float = 1.0,
        *,
        chunk_size: int = 128 * 1024,
        overwrite: bool = False,
        block_encoding: str = "cdr",
        writer: str = "inline",
        live: str = "",
    ) -> None:
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s, got {flush_interval_s!r}")
        if block_encoding not in ("cdr", "json"):
            raise ValueError(f"block_encoding must be 'cdr' or 'json', got {block_encoding!r}")
        if writer not in ("inline", "process"):
            raise ValueError(f"writer must be 'inline' or 'process', got {writer!r}")
        if live and writer != "process":
            raise ValueError("live: the live view is served by the writer process (writer='process')")
        given = {name: dict(values) for name, values in (metadata or {}).items()}
        session = given.pop(SESSION_METADATA, {})
        self.clock_offset_ns = (
            wall_clock_offset() if "clock_offset_ns" not in session else clock_offset(metadata_strings(session))
        )
        """Unix time minus the session clock, ns: a message's log time is its ``t_ns`` plus this."""
        self._t_end = _U64 - self.clock_offset_ns  # a t_ns from here on would not fit in a log time
        self.block_encoding = block_encoding
        self._cdr_blocks: dict[str, Any] = {}  # block topic -> its CdrBlock layout
        self.path = Path(path)
        self.flush_interval_s = float(flush_interval_s)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file = open(self.path, "wb" if overwrite else "xb")  # noqa: SIM115 - closed in close()
        except FileExistsError:
            raise OutputExistsError(
                f"recording {self.path} already exists; choose another path or pass overwrite=True"
            ) from None
        self._lock = threading.Lock()
        self._closed = False
        self._messages_written = 0
        self._channel_ids: dict[str, int] = {}  # topics written one message per sample (or per tick)
        self._block_ids: dict[str, int] = {}  # topics written in blocks
        self._schema_ids: dict[str, int] = {}
        self.start_monotonic_ns = time.monotonic_ns()
        library = f"hapticlab/{__version__}"
        self.writer = writer
        self.live_address = ""
        """Where the live view listens ("HOST:PORT"), "" without one."""
        self._sink: Sink
        try:
            if writer == "process":
                self._file.close()  # created here (an existing file refused here); the child writes it
                process = ProcessSink(self.path, library, self.flush_interval_s, chunk_size, live)
                self._sink, self.live_address = process, process.live_address
            else:
                self._sink = McapSink(self._file, library, self.flush_interval_s, chunk_size)
        except BaseException:
            self._file.close()
            if self.path.stat().st_size == 0:  # ours, created a moment ago, nothing in it: do not leave it behind
                self.path.unlink()
            raise
        try:
            version = FORMAT_VERSION if block_encoding == "cdr" else 2
            session = session_record(session, self.start_monotonic_ns, version, self.clock_offset_ns)
            self._sink.add_metadata(SESSION_METADATA, session)
            for name, values in given.items():
                self._sink.add_metadata(str(name), metadata_strings(values))
            self._sink.flush()
        except BaseException:
            self._sink.abort()
            raise

    # -- per-message path ---------------------------------------------------

    def write(self, topic: str, t_ns: int, message: Mapping[str, Any]) -> None:
        """Record ``message`` (a dict of lists/floats/ints/bools/str, numpy allowed) on ``topic`` at ``t_ns``.

        ``t_ns``: integer ns on the session's monotonic clock; the log (and
        publish) time is ``t_ns + clock_offset_ns`` (Unix time). Raises ``ValueError`` for an unknown topic or a bad
        time, ``TypeError`` for a value JSON cannot hold, ``RuntimeError``
        after :meth:`close`.
        """
        channel_id = self._channel_ids.get(topic)
        if channel_id is None:
            channel_id = self._register(topic, block=False)
        if type(t_ns) is not int:
            t_ns = operator.index(t_ns)  # numpy integers; floats raise TypeError
        if not 0 <= t_ns < self._t_end:
            raise ValueError(f"{topic}: t_ns must be a non-negative 64-bit integer (ns), got {t_ns}")
        self._add(topic, channel_id, t_ns, message)

    def write_block(self, topic: str, message: Mapping[str, Any]) -> None:
        """Record a block of samples on a sensor-rate topic as one columnar message (format 3, or 2 in JSON).

        ``message["t_ns"]`` holds each sample's time (integer ns on the session's
        monotonic clock, at least one); every other field is an array with one
        element per sample (numpy arrays, the fast path, or lists; (n, 3) for a
        3-vector), but for the estimator's ``params``/``cov_diag``, which
        describe the block's last sample (see :data:`~.schemas.BLOCK_LAST_SAMPLE_FIELDS`).
        A field left out is recorded as absent. The message's log time is the
        last sample's (plus ``clock_offset_ns``). Raises ``ValueError`` for a topic that is not written in
        blocks (or was written per sample in this file), bad times, a field of
        the wrong length or one the block does not have, ``TypeError`` for a
        value of the wrong type, ``RuntimeError`` after :meth:`close`.
        """
        channel_id = self._block_ids.get(topic)
        if channel_id is None:
            channel_id = self._register(topic, block=True)
        if self.block_encoding == "cdr":
            data, t_last = encode_block(self._cdr_blocks[topic], topic, message, _encode)
            self._add_bytes(channel_id, t_last, data)
            return
        try:
            given = t_ns = message["t_ns"]
            if type(t_ns) is not list or not all(type(t) is int for t in t_ns):
                t_ns = [operator.index(t) for t in t_ns]  # numpy arrays and integers; floats raise TypeError
            first, last = min(t_ns), max(t_ns)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"{topic}: a block needs t_ns, a non-empty list of integer times (ns)") from None
        if not (0 <= first and last < self._t_end):
            raise ValueError(f"{topic}: t_ns must be non-negative 64-bit integers (ns), got {first}..{last}")
        if t_ns is not given:
            message = {**message, "t_ns": t_ns}
        self._add(topic, channel_id, t_ns[-1], message)

    def _add(self, topic: str, channel_id: int, t_ns: int, message: Mapping[str, Any]) -> None:
        try:
            data = _encode(message)
        except TypeError as exc:
            raise TypeError(f"cannot record message on {topic}: {exc}") from None
        self._add_bytes(channel_id, t_ns, data)

    def _add_bytes(self, channel_id: int, t_ns: int, data: bytes) -> None:
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            self._sink.add_message(channel_id, t_ns + self.clock_offset_ns, data, self._messages_written & 0xFFFFFFFF)
            self._messages_written += 1

    def send(self) -> None:
        """Hand the messages written since the last send to the writer process (one per loop tick).

        Nothing to do with ``writer="inline"``. Raises :class:`~.process_sink.WriterProcessError`
        when the writer process has exited.
        """
        with self._lock:
            if not self._closed:
                self._sink.send()

    def event(self, t_ns: int, kind: str, message: str, **data: Any) -> None:
        """Record an event on ``/events``: ``kind`` tag, one-line ``message``, optional details."""
        record: dict[str, Any] = {"kind": kind, "message": message}
        if data:
            record["data"] = data
        self.write("/events", t_ns, record)

    def _register(self, topic: str, block: bool) -> int:
        # ValueError for unknown topics (and, in blocks, for topics written one message per sample)
        schema = block_schema_for_topic(topic) if block else schema_for_topic(topic)
        ids, other = (self._block_ids, self._channel_ids) if block else (self._channel_ids, self._block_ids)
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            channel_id = ids.get(topic)
            if channel_id is not None:
                return channel_id
            if topic in other:
                layout = "one message per sample" if block else "in blocks"
                raise ValueError(f"{topic} is already written {layout} in {self.path}; one layout per topic")
            if block and self.block_encoding == "cdr":
                cdr = cdr_block_for_topic(topic)
                title, encoding, message_encoding = cdr.name, "ros2msg", "cdr"
                data = cdr.definition.encode("utf-8")
                self._cdr_blocks[topic] = cdr
            else:
                title, encoding, message_encoding = schema["title"], "jsonschema", "json"
                data = json.dumps(schema, ensure_ascii=False).encode("utf-8")
            schema_id = self._schema_ids.get(title)
            if schema_id is None:
                schema_id = len(self._schema_ids) + 1  # MCAP schema ids start at 1 (0: no schema)
                self._sink.register_schema(schema_id, title, encoding, data)
                self._schema_ids[title] = schema_id
            channel_id = len(self._channel_ids) + len(self._block_ids)
            self._sink.register_channel(channel_id, topic, message_encoding, schema_id)
            ids[topic] = channel_id
            return channel_id

    # -- the rest -------------------------------------------------------------

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """Write a metadata record now (e.g. ``hapticlab.calibration`` once the sensor reported it)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            self._sink.add_metadata(str(name), metadata_strings(values))

    def flush(self) -> None:
        """Finish the chunk in progress and hand everything written so far to the OS."""
        with self._lock:
            if self._closed:
                return
            self._sink.flush()

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Write ``summary`` (if given) as ``hapticlab.summary``, finish the file. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                if summary is not None:
                    values = dict(summary)
                    values.setdefault("end_time", utc_now_iso())
                    values.setdefault("messages_written", self._messages_written)
                    self._sink.add_metadata(SUMMARY_METADATA, metadata_strings(values))
            finally:
                self._sink.finish()

    @property
    def messages_written(self) -> int:
        """Number of messages recorded so far."""
        return self._messages_written

    @property
    def writer_pid(self) -> int | None:
        """The writer process's pid (``writer="process"``), None when the writer runs in this process."""
        return self._sink.pid if isinstance(self._sink, ProcessSink) else None

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def topics(self) -> list[str]:
        """Topics that have a channel in this recording so far."""
        return [*self._channel_ids, *self._block_ids]

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Recorder({str(self.path)!r}, {state}, {self._messages_written} messages)"
