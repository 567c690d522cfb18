"""Session recording: every session goes to one MCAP file; every offline tool reads one stream type.

``schemas`` (topics, JSON schemas, metadata record names), ``writer``
(:class:`Recorder`: zstd chunks flushed about once a second), ``reader``
(:func:`read_recording`, :func:`iter_messages`), ``recover`` (salvage a file
whose writer died), ``csvimport`` (the CSV import contract) and ``stream``
(:class:`Stream`, the one offline stream type, from a CSV or an MCAP file).
"""

from .reader import Recording, RecordingError, iter_messages, open_recording, read_recording
from .recover import recover
from .schemas import ESTIMATOR_SCHEMA, ESTIMATOR_TOPIC_PREFIX, MCAP_MAGIC, SCHEMAS, TOPICS, schema_for_topic
from .stream import Stream, load_stream
from .writer import Recorder

__all__ = [
    "ESTIMATOR_SCHEMA",
    "ESTIMATOR_TOPIC_PREFIX",
    "MCAP_MAGIC",
    "SCHEMAS",
    "TOPICS",
    "Recorder",
    "Recording",
    "RecordingError",
    "Stream",
    "iter_messages",
    "load_stream",
    "open_recording",
    "read_recording",
    "recover",
    "schema_for_topic",
]
