"""Reading a recording: one :class:`Recording` shape, opened lazily or read into memory.

:func:`open_recording` reads the metadata and the channel list and decodes a
topic only when it is asked for (``messages(topic)`` streams it);
:func:`read_recording` reads every topic (or the given ones) at once;
:func:`iter_messages` streams ``(topic, t_ns, message)`` over several topics.
(both streamed by :mod:`.messages`). Messages are decoded by their channel's
encoding (:data:`.messages.DECODERS`).

The three layouts (``schemas.FORMAT_VERSION``) read the same: a block message
of format 2 (a JSON channel whose schema is a block schema) or 3 (a ``cdr``
channel with a CDR block schema, :mod:`.cdr`) comes out as one ``(t_ns,
message)`` per sample, exactly the messages format 1 recorded one by one
(lists; ``params``/``cov_diag`` on the block's last sample, None on the
others; a non-finite float as None, as JSON's null); :meth:`Recording.field`,
:meth:`Recording.t_ns` and :meth:`Recording.estimates` concatenate a block
topic's arrays without building the per-sample messages (NaN for every
non-finite float, ±inf too, as formats 1 and 2 read their null).

A file that is not MCAP, or is truncated or damaged, is a
:class:`~.mcapfile.RecordingError` with one line that says what is wrong (and
to run ``hapticlab recover``).
"""

from __future__ import annotations

import gc
import os
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from dataclasses import field as _dc_field
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.types import Estimates, Event
from hapticlab.sessions.recording.blocks import block_times, cdr_block_field, expand_block, stack
from hapticlab.sessions.recording.mcapfile import json_loads, read_head
from hapticlab.sessions.recording.messages import decode_messages, iter_messages, iter_raw
from hapticlab.sessions.recording.schemas import BLOCK_LAST_SAMPLE_FIELDS, SESSION_METADATA


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
            return block_times(blocks)
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
        return stack(values)

    def _blocks(self, topic: str) -> list[dict[str, Any]] | None:
        """The block messages of ``topic`` when all of it is blocks whose samples are in time order, else None."""
        if topic not in self.topics:
            self._msgs(topic)  # the KeyError naming the topics present
        return self.blocks.get(topic)

    def _block_field(self, topic: str, blocks: list[dict[str, Any]], name: str) -> np.ndarray:
        if blocks and isinstance(blocks[0]["t_ns"], np.ndarray):
            return cdr_block_field(topic, blocks, name)
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
        return stack(values)

    def meta(self, record: str, key: str, default: Any = None) -> Any:
        """A metadata value, JSON-decoded when it is JSON (else the raw string)."""
        raw = self.metadata.get(record, {}).get(key)
        if raw is None:
            return default
        try:
            return json_loads(raw)
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
                self.loaded[topic] = [item for b in blocks for item in expand_block(topic, b)]
            else:
                self.loaded[topic] = _read_topics(self.path, [topic])[0].get(topic, [])
        return self.loaded[topic]

    def __iter__(self):
        return iter(self.counts)

    def __len__(self) -> int:
        return len(self.counts)


def open_recording(path: str | os.PathLike[str]) -> Recording:
    """Open a recording: metadata and topics now, each topic's messages when first asked for.

    Raises :class:`RecordingError` with one line when the file is not MCAP, or
    is truncated or damaged (the message says to run ``hapticlab recover``).
    """
    path = Path(path)
    metadata, schemas, counts, block_topics = read_head(path)
    topics = _LazyTopics(path, counts, block_topics)
    return Recording(path=path, metadata=metadata, topics=topics, schemas=schemas, blocks=_LazyBlocks(topics))


def read_recording(path: str | os.PathLike[str], topics: Iterable[str] | str | None = None) -> Recording:
    """Read a recording into memory (optionally only some ``topics``).

    Raises :class:`RecordingError` (a ``ValueError``) with a one-line message
    when the file is not MCAP, or is truncated or damaged (the message says to
    run ``hapticlab recover``).
    """
    path = Path(path)
    metadata, schemas, _, _ = read_head(path)
    samples, blocks = _read_topics(path, topics)
    return Recording(path=path, metadata=metadata, topics=samples, schemas=schemas, blocks=blocks)


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
        for block, topic, t_ns, message in decode_messages(iter_raw(path, topics, log_time_order=False), path):
            if block:
                blocks.setdefault(topic, []).append(message)
                if expand:
                    out.setdefault(topic, []).extend(expand_block(topic, message))
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
        t = block_times(blocks[topic])
        if topic in per_sample or bool((np.diff(t) < 0).any()):
            del blocks[topic]  # not all blocks, or the blocks' order is not the samples'
    return out, blocks
