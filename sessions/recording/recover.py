"""Salvaging a recording whose writer died (:func:`recover`)."""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from hapticlab.core.version import __version__
from hapticlab.sessions.output import atomic_output, check_output
from hapticlab.sessions.recording.mcapfile import RecordingError
from hapticlab.sessions.recording.metadata import metadata_strings, utc_now_iso
from hapticlab.sessions.recording.schemas import MCAP_MAGIC, RECOVERED_METADATA

_KNOWN_OPCODES = {int(op) for op in Opcode}


def recover(
    broken_path: str | os.PathLike[str], fixed_path: str | os.PathLike[str], force: bool = False
) -> dict[str, Any]:
    """Salvage a recording whose writer died (no footer/summary) into a valid MCAP file.

    Reads the file front to back without seeking to the end; keeps every
    complete record: metadata, schemas, channels, and the messages of every
    complete chunk whose CRC checks out (a damaged chunk is skipped, the scan
    goes on). The scan stops at the first incomplete or unreadable record (the
    lost tail) or at the end of the data section of a complete file. Schemas,
    channels (topics, encodings, channel metadata) and metadata records are
    re-written as found, messages keep their log/publish times and sequence
    numbers; a ``hapticlab.recovered`` metadata record says what happened.

    Returns ``{"messages": n, "topics": {topic: n}, "lost_tail_bytes": k,
    "chunks": salvaged chunks, "corrupt_chunks": skipped, "orphan_messages":
    messages whose channel was lost, "metadata": [record names], "complete":
    the input had a proper end, "last_t_ns": latest log time (as the file holds it: Unix time in a
    recording with a ``clock_offset_ns``) or None}``.
    Raises :class:`RecordingError` when the input is not an MCAP file. The
    output is checked first (its folder must exist; an existing file is refused
    unless ``force``) and written whole or not at all (``sessions.output``).
    """
    src = Path(broken_path)
    if src.exists() and not src.is_file():  # refused before it is opened: a FIFO blocks, a device never ends
        raise RecordingError(f"{src}: not a regular file (a folder, a device or a FIFO); give an MCAP file")
    dst = check_output(fixed_path, force, label="-o", inputs=[src], role="broken input")
    size = src.stat().st_size

    stats: dict[str, Any] = {
        "messages": 0,
        "topics": {},
        "lost_tail_bytes": 0,
        "chunks": 0,
        "corrupt_chunks": 0,
        "orphan_messages": 0,
        "metadata": [],
        "complete": False,
        "last_t_ns": None,
    }
    schemas: dict[int, Schema] = {}
    schema_map: dict[int, int] = {}  # old schema id -> new
    channel_map: dict[int, tuple[int, str]] = {}  # old channel id -> (new id, topic)
    topic_counts: dict[str, int] = stats["topics"]

    with open(src, "rb") as f:
        magic = f.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            if len(magic) < len(MCAP_MAGIC) and MCAP_MAGIC.startswith(magic):
                raise RecordingError(f"{src} is cut off inside the MCAP magic bytes: nothing to recover")
            raise RecordingError(f"{src} is not an MCAP file (bad magic bytes at the start): nothing to recover")
        with atomic_output(dst, force, label="-o") as tmp, open(tmp, "wb") as out_file:
            writer = Writer(out_file, compression=CompressionType.ZSTD)
            started = False

            def start(profile: str = "") -> None:
                nonlocal started
                if not started:
                    writer.start(profile=profile, library=f"hapticlab-recover/{__version__}")
                    started = True

            def on_schema(schema: Schema) -> None:
                if schema.id in schemas:
                    return
                schemas[schema.id] = schema
                start()
                schema_map[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)

            def on_channel(channel: Channel) -> None:
                if channel.id in channel_map:
                    return
                if channel.schema_id != 0 and channel.schema_id not in schema_map:
                    return  # its schema was lost: its messages become orphans
                start()
                new_id = writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schema_map.get(channel.schema_id, 0),
                    dict(channel.metadata),
                )
                channel_map[channel.id] = (new_id, channel.topic)

            def on_message(message: Message) -> None:
                target = channel_map.get(message.channel_id)
                if target is None:
                    stats["orphan_messages"] += 1
                    return
                new_id, topic = target
                writer.add_message(new_id, message.log_time, message.data, message.publish_time, message.sequence)
                stats["messages"] += 1
                topic_counts[topic] = topic_counts.get(topic, 0) + 1
                last = stats["last_t_ns"]
                if last is None or message.log_time > last:
                    stats["last_t_ns"] = message.log_time

            pos = len(MCAP_MAGIC)
            while True:
                if pos + 9 > size:
                    break
                f.seek(pos)
                opcode, length = struct.unpack("<BQ", f.read(9))
                if opcode not in _KNOWN_OPCODES or pos + 9 + length > size:
                    break  # incomplete (or garbage) record: the lost tail starts here
                body = f.read(length)
                stream = ReadDataStream(io.BytesIO(body))
                try:
                    if opcode == Opcode.HEADER:
                        start(Header.read(stream).profile)
                    elif opcode == Opcode.SCHEMA:
                        on_schema(Schema.read(stream))
                    elif opcode == Opcode.CHANNEL:
                        on_channel(Channel.read(stream))
                    elif opcode == Opcode.MESSAGE:
                        on_message(Message.read(stream, length))
                    elif opcode == Opcode.METADATA:
                        record = Metadata.read(stream)
                        start()
                        writer.add_metadata(record.name, dict(record.metadata))
                        stats["metadata"].append(record.name)
                    elif opcode == Opcode.ATTACHMENT:
                        att = Attachment.read(stream)
                        start()
                        writer.add_attachment(att.create_time, att.log_time, att.name, att.media_type, att.data)
                    elif opcode == Opcode.CHUNK:
                        try:
                            records = breakup_chunk(Chunk.read(stream), validate_crc=True)
                        except Exception:  # bad CRC, bad compression, garbage inside
                            stats["corrupt_chunks"] += 1
                        else:
                            stats["chunks"] += 1
                            for rec in records:
                                if isinstance(rec, Message):
                                    on_message(rec)
                                elif isinstance(rec, Channel):
                                    on_channel(rec)
                                elif isinstance(rec, Schema):
                                    on_schema(rec)
                    elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                        stats["complete"] = True
                        pos = size
                        break
                    # message indexes, chunk indexes, statistics...: rebuilt by the writer
                except Exception:
                    break  # a record whose length fits but whose content does not parse
                pos += 9 + length
            stats["lost_tail_bytes"] = 0 if stats["complete"] else size - pos
            if not started:  # not one complete record: an empty "recovered" file would only replace the output
                raise RecordingError(f"{src} has no complete MCAP record after the magic bytes: nothing to recover")
            start()
            writer.add_metadata(
                RECOVERED_METADATA,
                metadata_strings(
                    {
                        "source": str(src),
                        "recovered_at": utc_now_iso(),
                        "messages": stats["messages"],
                        "lost_tail_bytes": stats["lost_tail_bytes"],
                        "corrupt_chunks": stats["corrupt_chunks"],
                        "orphan_messages": stats["orphan_messages"],
                        "complete": stats["complete"],
                    }
                ),
            )
            writer.finish()
    return stats
