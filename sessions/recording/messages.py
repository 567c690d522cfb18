"""A recording's messages streamed and decoded, without loading the file.

:func:`iter_messages` gives ``(topic, t_ns, message)`` in log-time order, one
per sample whatever the layout; :func:`iter_blocks` gives block messages whole
and columnar, in file order (the fast way through a long file). Messages are
decoded by their channel's encoding (:data:`DECODERS`); a CDR block by
:mod:`.cdr`.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.records import Channel, Message

from hapticlab.sessions.recording.blocks import as_columns, check_block, expand_block
from hapticlab.sessions.recording.cdr import CdrBlockError, decode_block
from hapticlab.sessions.recording.mcapfile import (
    RecordingError,
    block_kind,
    check_mcap,
    damaged,
    json_loads,
    log_offset,
    open_reader,
)
from hapticlab.sessions.recording.schemas import BLOCK_LAST_SAMPLE_FIELDS, BLOCK_TOPICS, ESTIMATOR_TOPIC_PREFIX

DECODERS: dict[str, Any] = {"json": json_loads}
"""Message encoding (the MCAP channel's) -> function from the message bytes to a dict."""


def iter_raw(
    path: Path, topics: Iterable[str] | str | None, log_time_order: bool = True
) -> Iterator[tuple[Any, Channel, Message]]:
    """``(block kind (see block_kind), channel, message)`` of ``topics`` (all when None)."""
    f, reader, _ = open_reader(path)
    with f:
        topic_list = [topics] if isinstance(topics, str) else (list(topics) if topics is not None else None)
        try:
            for schema, channel, message in reader.iter_messages(topics=topic_list, log_time_order=log_time_order):
                yield block_kind(schema, channel), channel, message
        except (McapError, struct.error, EOFError, ValueError, KeyError) as exc:
            raise damaged(path, exc) from None
        except Exception as exc:  # zstd errors and the like
            if type(exc).__module__.startswith(("zstandard", "mcap")):
                raise damaged(path, exc) from None
            raise


def iter_messages(
    path: str | os.PathLike[str], topics: Iterable[str] | str | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """Stream ``(topic, t_ns, message)`` in log-time order without loading the file (``t_ns`` on the session clock).

    ``topics`` limits the topics read (chunks without them are skipped). A
    block message (format 2) comes out as one message per sample, each at its
    own time (blocks are in log-time order, the last sample's time).
    Raises :class:`RecordingError` for a file that is not MCAP or is truncated.
    """
    path = Path(path)
    check_mcap(path)  # fail here, not at the first next()
    return _expanded(decode_messages(iter_raw(path, topics), path), path)


def iter_blocks(
    path: str | os.PathLike[str], topics: Iterable[str] | str | None = None
) -> Iterator[tuple[str, int, dict[str, Any], bool]]:
    """Stream ``(topic, time ns, message, is a block)`` in file order, blocks kept whole (the time: the log time on
    the session clock).

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
    check_mcap(path)
    for block, topic, t_ns, message in decode_messages(iter_raw(path, topics, log_time_order=False), path):
        if block:
            yield topic, t_ns, as_columns(message), True
        elif topic in BLOCK_TOPICS or topic.startswith(ESTIMATOR_TOPIC_PREFIX):
            yield (
                topic,
                t_ns,
                as_columns(
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


def _decoder(path: Path, channel: Channel):
    try:
        return DECODERS[channel.message_encoding]
    except KeyError:
        raise RecordingError(
            f"{path}: topic {channel.topic} has message encoding "
            f"{channel.message_encoding!r}; hapticlab reads {', '.join(DECODERS)}"
        ) from None


def decode_messages(
    raw: Iterator[tuple[Any, Channel, Message]], path: Path
) -> Iterator[tuple[bool, str, int, dict[str, Any]]]:
    """``(is a block, topic, time, decoded message)``, the time the log time on the session clock (minus
    :func:`~.mcapfile.log_offset`); a block message is checked."""
    decoders: dict[int, Any] = {}
    offset = log_offset(path)
    for block, channel, message in raw:
        t_ns = message.log_time - offset
        if block is None or block == "json":
            decode = decoders.get(channel.id) or decoders.setdefault(channel.id, _decoder(path, channel))
            decoded = decode(message.data)
            if block:
                check_block(path, channel.topic, t_ns, decoded)
        else:
            try:
                decoded = decode_block(block, message.data, json_loads)
            except (CdrBlockError, UnicodeDecodeError, ValueError) as exc:
                raise RecordingError(f"{path.name}: {channel.topic} block message at {t_ns} ns: {exc}") from None
        yield block is not None, channel.topic, t_ns, decoded


def _expanded(
    decoded: Iterator[tuple[bool, str, int, dict[str, Any]]], path: Path
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    for block, topic, t_ns, message in decoded:
        if block:
            for t, m in expand_block(topic, message):
                yield topic, t, m
        else:
            yield topic, t_ns, message
