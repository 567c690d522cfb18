"""Session recording: every session goes to one MCAP file; every offline tool reads one stream type.

Writing: ``schemas`` (topics, JSON schemas, metadata record names, the three
layouts), ``cdr_layouts`` and ``cdr`` (format 3's binary blocks), ``writer``
(:class:`Recorder`: zstd chunks flushed about once a second), ``metadata``,
``sinks`` and ``process_sink`` (the MCAP writer in this process or in its own).
Reading: ``mcapfile`` (:class:`RecordingError`, the file checked and opened),
``messages`` (:func:`iter_messages`, :func:`iter_blocks`: every layout),
``blocks``, ``reader`` (:class:`Recording`, :func:`open_recording`,
:func:`read_recording`), ``columnar`` (a long file a chunk at a time),
``recover`` (salvage a file whose writer died). Offline: ``stream``
(:class:`Stream`, the one offline stream type), made by ``csvimport`` (the CSV
import contract) or ``mcapimport`` (a session recording), ``loader``
(:func:`load_stream`: either, by the file's suffix).
"""

from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.mcapfile import RecordingError
from hapticlab.sessions.recording.messages import iter_blocks, iter_messages
from hapticlab.sessions.recording.reader import Recording, open_recording, read_recording
from hapticlab.sessions.recording.recover import recover
from hapticlab.sessions.recording.schemas import (
    BLOCK_TOPICS,
    ESTIMATOR_BLOCK_SCHEMA,
    ESTIMATOR_SCHEMA,
    ESTIMATOR_TOPIC_PREFIX,
    FORMAT_VERSION,
    MCAP_MAGIC,
    SCHEMAS,
    TOPICS,
    block_schema_for_topic,
    schema_for_topic,
)
from hapticlab.sessions.recording.stream import Stream
from hapticlab.sessions.recording.writer import Recorder

__all__ = [
    "BLOCK_TOPICS",
    "ESTIMATOR_BLOCK_SCHEMA",
    "ESTIMATOR_SCHEMA",
    "ESTIMATOR_TOPIC_PREFIX",
    "FORMAT_VERSION",
    "MCAP_MAGIC",
    "SCHEMAS",
    "TOPICS",
    "Recorder",
    "Recording",
    "RecordingError",
    "Stream",
    "block_schema_for_topic",
    "iter_blocks",
    "iter_messages",
    "load_stream",
    "open_recording",
    "read_recording",
    "recover",
    "schema_for_topic",
]
