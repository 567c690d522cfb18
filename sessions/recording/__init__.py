"""Session recording: every session goes to one MCAP file; every offline tool reads one stream type.

``schemas`` (topics, JSON schemas, metadata record names, the two layouts:
format 2 writes the sensor-rate topics in blocks), ``writer`` (:class:`Recorder`:
zstd chunks flushed about once a second), ``reader`` (:func:`read_recording`,
:func:`iter_messages`: both layouts, one message per sample), ``recover`` (salvage a file
whose writer died), ``csvimport`` (the CSV import contract) and ``stream``
(:class:`Stream`, the one offline stream type, from a CSV or an MCAP file).
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
    "iter_blocks",
    "block_schema_for_topic",
    "iter_messages",
    "load_stream",
    "open_recording",
    "read_recording",
    "recover",
    "schema_for_topic",
]
