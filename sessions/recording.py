"""Session recording: every session goes to one MCAP file.

Writing (:class:`Recorder`)
    One ``mcap`` writer per session, zstd-compressed chunks, JSON messages on
    JSON-schema channels (viewable in Foxglove). The chunk in progress is
    finished and flushed to the OS about once a second (``time.monotonic``,
    checked on every write) and on close, so a crash of the process loses at
    most the last second; :func:`recover` salvages the rest of a file whose
    writer died. Log time and publish time of a message are its ``t_ns``
    (integer ns on the session's monotonic clock).

Topics (contract, see DESIGN.md "Recording (MCAP)"; SI units, frames in the
field names): ``/sensor/wrench``, ``/kinematics/pose``, ``/aligned/sample``,
``/estimator/<name>`` (one channel per estimator, one shared schema),
``/haptic/command``, ``/haptic/state``, ``/events``. Any other topic is
refused with a ``ValueError``. :data:`SCHEMAS` holds the JSON schemas.

Non-finite floats (NaN, ±inf) are not valid JSON; they are recorded as
``null`` (and read back by :meth:`Recording.field` as NaN).

Metadata (MCAP Metadata records, string values; non-string values given by the
caller are JSON-encoded): ``hapticlab.session`` (resolved config, plugins,
hapticlab version, git revision where known, start time), ``hapticlab.calibration``
(whatever the caller gives), ``hapticlab.summary`` at close when given, and
``hapticlab.recovered`` in files written by :func:`recover`.

Reading: :func:`read_recording` (whole file into memory), :func:`iter_messages`
(streaming), :func:`recover` (salvage a truncated file).
"""

from __future__ import annotations

import datetime as _dt
import gc
import io
import json
import math
import operator
import os
import platform
import re
import struct
import subprocess
import threading
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field as _dc_field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

__all__ = [
    "ESTIMATOR_TOPIC_PREFIX",
    "MCAP_MAGIC",
    "SCHEMAS",
    "TOPICS",
    "Recorder",
    "Recording",
    "RecordingError",
    "iter_messages",
    "read_recording",
    "recover",
    "schema_for_topic",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
ESTIMATOR_TOPIC_PREFIX = "/estimator/"
_ESTIMATOR_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*\Z")
_JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

SESSION_METADATA = "hapticlab.session"
CALIBRATION_METADATA = "hapticlab.calibration"
SUMMARY_METADATA = "hapticlab.summary"
RECOVERED_METADATA = "hapticlab.recovered"


class RecordingError(ValueError):
    """A recording that cannot be read: not an MCAP file, truncated or corrupt."""


# --------------------------------------------------------------------------
# JSON schemas (draft 2020-12), one per topic; estimator channels share one.
# --------------------------------------------------------------------------

_NUM = {"type": ["number", "null"]}  # null marks a non-finite value (NaN/inf)


def _vec(n: int, description: str) -> dict[str, Any]:
    return {
        "type": "array",
        "items": _NUM,
        "minItems": n,
        "maxItems": n,
        "description": description,
    }


def _quat(description: str) -> dict[str, Any]:
    return _vec(4, description + " Unit quaternion [w, x, y, z].")


def _schema(title: str, description: str, properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {
        "$schema": _JSON_SCHEMA_DIALECT,
        "title": title,
        "description": description + " Non-finite numbers are recorded as null.",
        "type": "object",
        "properties": properties,
        "required": required,
    }


_WRENCH_SCHEMA = _schema(
    "hapticlab.SensorWrench",
    "One raw reading of the six-axis force/torque sensor.",
    {
        "force_S": _vec(3, "Raw force in the sensor frame S, N."),
        "torque_S": _vec(3, "Raw torque in S about the sensor origin, N·m."),
        "seq": {
            "type": "integer",
            "description": "Device sequence number (NetFT RDT sequence or a counter).",
        },
        "status": {
            "type": "integer",
            "description": "Device status bits; 0 = good, 1 = saturated, 2 = device error.",
        },
    },
    ["force_S", "torque_S", "seq", "status"],
)

_POSE_SCHEMA = _schema(
    "hapticlab.KinematicsPose",
    "One forward-kinematics reading of the robot end (flange) frame E in the robot base frame B.",
    {
        "quat_BE": _quat("Orientation R_BE of the end frame E in the base frame B."),
        "p_BoEo_B": {
            **_vec(3, "Position of E's origin from B's origin, expressed in B, m; null when unknown."),
            "type": ["array", "null"],
        },
        "joints": {
            "type": ["array", "null"],
            "items": _NUM,
            "description": "Joint positions, rad (m for prismatic joints); null when unknown.",
        },
    },
    ["quat_BE"],
)

_ALIGNED_SCHEMA = _schema(
    "hapticlab.AlignedSample",
    "A wrench sample paired with the robot orientation interpolated at the sample's own time.",
    {
        "force_S": _vec(3, "Raw force in the sensor frame S, N."),
        "torque_S": _vec(3, "Raw torque in S, N·m."),
        "quat_BE": _quat("Orientation R_BE of E in B at the sample's time (the estimator uses R_EB = R_BEᵀ)."),
        "seq": {"type": "integer", "description": "Sensor sequence number of the sample."},
        "status": {"type": "integer", "description": "Sensor status bits; 0 = good."},
        "stale": {
            "type": "boolean",
            "description": (
                "True when the orientation was held longer than one kinematics period past the last pose."
            ),
        },
    },
    ["force_S", "torque_S", "quat_BE", "seq", "status", "stale"],
)

_ESTIMATOR_SCHEMA = _schema(
    "hapticlab.EstimatorEstimate",
    "One estimator's output for one sample (channel /estimator/<name>).",
    {
        "contact_force_S": _vec(3, "Estimated tool-tissue contact force in the sensor frame S, N."),
        "contact_torque_S": _vec(3, "Estimated contact torque in S, N·m."),
        "contact": {"type": "boolean", "description": "The estimator judged the sample to be in contact."},
        "converged_force": {"type": "boolean", "description": "The force stage has converged."},
        "converged_torque": {"type": "boolean", "description": "The torque stage has converged."},
        "params": {
            "type": "object",
            "additionalProperties": {"type": "array", "items": _NUM},
            "description": (
                "Current parameter estimates, name -> list of floats, SI units and frames in the names "
                "(gravity_force_B N, bias_force_S N, cog_S m, bias_torque_S N·m, ...)."
            ),
        },
        "cov_diag": {
            "type": "array",
            "items": _NUM,
            "description": "Diagonal of the parameter covariance, in the squared units of the parameters.",
        },
    },
    ["contact_force_S", "contact_torque_S", "contact", "converged_force", "converged_torque"],
)

_COMMAND_SCHEMA = _schema(
    "hapticlab.HapticCommand",
    "Force command sent to the haptic master device.",
    {
        "force_D": _vec(3, "Force on the handle in the device base frame D, N."),
        "enabled": {"type": "boolean", "description": "False when the output is held at zero for safety."},
        "reason": {
            "type": "string",
            "description": "Why the output is disabled; present when enabled is false.",
        },
    },
    ["force_D", "enabled"],
)

_STATE_SCHEMA = _schema(
    "hapticlab.HapticState",
    "State reported by the haptic master device.",
    {
        "pose": {
            "type": "object",
            "description": "Pose of the handle frame H in the device base frame D.",
            "properties": {
                "quat_DH": _quat("Orientation R_DH of the handle H in the device base D."),
                "p_DoHo_D": _vec(3, "Position of H's origin from D's origin, expressed in D, m."),
            },
            "required": ["quat_DH", "p_DoHo_D"],
        },
        "buttons": {"type": "integer", "description": "Bit mask of pressed buttons."},
    },
    ["pose", "buttons"],
)

_EVENT_SCHEMA = _schema(
    "hapticlab.Event",
    "Something a person reviewing the session should know about.",
    {
        "kind": {
            "type": "string",
            "description": "Short machine-readable tag, e.g. haptic_disabled, converged.",
        },
        "message": {"type": "string", "description": "One human-readable line."},
        "data": {"type": "object", "description": "Optional details (SI units, frames in the names)."},
    },
    ["kind", "message"],
)

#: Fixed topics -> JSON schema. Estimator topics (``/estimator/<name>``) use :data:`ESTIMATOR_SCHEMA`.
TOPICS: dict[str, dict[str, Any]] = {
    "/sensor/wrench": _WRENCH_SCHEMA,
    "/kinematics/pose": _POSE_SCHEMA,
    "/aligned/sample": _ALIGNED_SCHEMA,
    "/haptic/command": _COMMAND_SCHEMA,
    "/haptic/state": _STATE_SCHEMA,
    "/events": _EVENT_SCHEMA,
}
ESTIMATOR_SCHEMA = _ESTIMATOR_SCHEMA
#: Schema title -> JSON schema, every schema a recording may contain.
SCHEMAS: dict[str, dict[str, Any]] = {s["title"]: s for s in (*TOPICS.values(), ESTIMATOR_SCHEMA)}


def schema_for_topic(topic: str) -> dict[str, Any]:
    """The JSON schema of ``topic``; ``ValueError`` naming the topic when it is not a recording topic."""
    schema = TOPICS.get(topic)
    if schema is not None:
        return schema
    if topic.startswith(ESTIMATOR_TOPIC_PREFIX):
        name = topic[len(ESTIMATOR_TOPIC_PREFIX) :]
        if _ESTIMATOR_NAME.match(name):
            return ESTIMATOR_SCHEMA
        raise ValueError(
            f"bad estimator topic {topic!r}: the name after /estimator/ must be "
            "letters, digits, '_', '.' or '-'"
        )
    raise ValueError(
        f"unknown recording topic {topic!r}; known topics: {', '.join(TOPICS)}, /estimator/<name>"
    )


# --------------------------------------------------------------------------
# JSON encoding
# --------------------------------------------------------------------------


def _json_default(obj: Any) -> Any:
    """Encode numpy arrays/scalars (and paths) that ``json`` does not know."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serializable")


def _finite(obj: Any) -> Any:
    """Copy of ``obj`` with numpy converted and non-finite floats replaced by None (slow path)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, np.ndarray):
        return _finite(obj.tolist())
    if isinstance(obj, np.generic):
        return _finite(obj.item())
    if isinstance(obj, Mapping):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


# One encoder, built once: json.dumps(default=...) would build a new encoder per call.
_encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_json_default).encode
_encode_meta = json.JSONEncoder(separators=(",", ":"), allow_nan=True, default=_json_default).encode


def _metadata_strings(values: Mapping[str, Any]) -> dict[str, str]:
    """MCAP metadata values must be strings: keep strings, JSON-encode everything else."""
    out: dict[str, str] = {}
    for key, value in values.items():
        out[str(key)] = value if isinstance(value, str) else _encode_meta(value)
    return out


@lru_cache(maxsize=1)
def git_revision() -> str | None:
    """The git commit of the hapticlab source tree, or None when it is not a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        result = subprocess.run(
            ["git", "-C", str(here), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=2.0,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    rev = result.stdout.strip()
    return rev if result.returncode == 0 and rev else None


def _hapticlab_version() -> str:
    try:
        from hapticlab import __version__
    except ImportError:  # pragma: no cover - only when imported outside the package
        return "unknown"
    return str(__version__)


def _utc_now_iso() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------

_U64 = 1 << 64
_monotonic = time.monotonic


class Recorder:
    """Write one session to one MCAP file.

    Args:
        path: output ``.mcap`` file. Parent folders are created.
        metadata: metadata records to write at the start, ``{record name: {key: value}}``;
            values that are not strings are JSON-encoded. The ``hapticlab.session``
            record is always written; ``hapticlab_version``, ``git_revision`` (where
            known), ``start_time`` (UTC, ISO 8601), ``start_monotonic_ns`` (the session
            clock at that instant), ``python`` and ``mcap`` are filled in unless given.
            Put the resolved config under ``config`` and plugin names/versions under
            ``plugins``; put counts per unit etc. in ``hapticlab.calibration``.
        flush_interval_s: finish the chunk in progress and flush it to the OS when
            this much ``time.monotonic`` time has passed since the last flush (checked
            on each write). A crash loses at most this much data.
        chunk_size: uncompressed bytes after which a chunk is finished early. The
            write that finishes a chunk pays for its zstd compression (about 0.3-0.5 ms
            for the default 128 KiB, 2-7 ms for 1 MiB on a slow core), so smaller
            chunks mean smaller latency spikes (at ~7 % worse compression).
        overwrite: replace an existing file; by default an existing file is an
            error (a previous recording is never silently destroyed).

    ``write`` is the per-sample path (1-7 kHz, several topics per sample): one
    JSON encode, one dict lookup, one ``mcap`` add. It is thread-safe.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        metadata: Mapping[str, Mapping[str, Any]] | None = None,
        flush_interval_s: float = 1.0,
        *,
        chunk_size: int = 128 * 1024,
        overwrite: bool = False,
    ) -> None:
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be > 0 s, got {flush_interval_s!r}")
        self.path = Path(path)
        self.flush_interval_s = float(flush_interval_s)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file = open(self.path, "wb" if overwrite else "xb")  # noqa: SIM115 - closed in close()
        except FileExistsError:
            raise FileExistsError(
                f"recording {self.path} already exists; choose another path or pass overwrite=True"
            ) from None
        self._lock = threading.Lock()
        self._closed = False
        self._messages_written = 0
        self._channel_ids: dict[str, int] = {}
        self._schema_ids: dict[str, int] = {}
        self.start_monotonic_ns = time.monotonic_ns()
        try:
            self._writer = Writer(
                self._file,
                chunk_size=int(chunk_size),
                compression=CompressionType.ZSTD,
            )
            self._writer.start(profile="", library=f"hapticlab/{_hapticlab_version()}")
            given = {name: dict(values) for name, values in (metadata or {}).items()}
            session = given.pop(SESSION_METADATA, {})
            session.setdefault("hapticlab_version", _hapticlab_version())
            rev = git_revision()
            if rev is not None:
                session.setdefault("git_revision", rev)
            session.setdefault("start_time", _utc_now_iso())
            session.setdefault("start_monotonic_ns", self.start_monotonic_ns)
            session.setdefault("python", platform.python_version())
            session.setdefault("mcap", _mcap_version())
            self._writer.add_metadata(SESSION_METADATA, _metadata_strings(session))
            for name, values in given.items():
                self._writer.add_metadata(str(name), _metadata_strings(values))
            self._writer.flush()
        except BaseException:
            self._file.close()
            raise
        self._next_flush = _monotonic() + self.flush_interval_s

    # -- per-message path ---------------------------------------------------

    def write(self, topic: str, t_ns: int, message: Mapping[str, Any]) -> None:
        """Record ``message`` (a dict of lists/floats/ints/bools/str, numpy allowed) on ``topic`` at ``t_ns``.

        ``t_ns`` is the log (and publish) time: integer ns on the session's
        monotonic clock. Raises ``ValueError`` for an unknown topic or a bad
        time, ``TypeError`` for a value JSON cannot hold, ``RuntimeError``
        after :meth:`close`.
        """
        channel_id = self._channel_ids.get(topic)
        if channel_id is None:
            channel_id = self._register(topic)
        if type(t_ns) is not int:
            t_ns = operator.index(t_ns)  # numpy integers; floats raise TypeError
        if not 0 <= t_ns < _U64:
            raise ValueError(f"{topic}: t_ns must be a non-negative 64-bit integer (ns), got {t_ns}")
        try:
            data = _encode(message)
        except ValueError:  # NaN or inf somewhere: record them as null
            data = _encode(_finite(message))
        except TypeError as exc:
            raise TypeError(f"cannot record message on {topic}: {exc}") from None
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            seq = self._messages_written & 0xFFFFFFFF
            self._writer.add_message(channel_id, t_ns, data.encode(), t_ns, seq)
            self._messages_written += 1
            now = _monotonic()
            if now >= self._next_flush:
                self._writer.flush()
                self._next_flush = now + self.flush_interval_s

    def event(self, t_ns: int, kind: str, message: str, **data: Any) -> None:
        """Record an event on ``/events``: ``kind`` tag, one-line ``message``, optional details."""
        record: dict[str, Any] = {"kind": kind, "message": message}
        if data:
            record["data"] = data
        self.write("/events", t_ns, record)

    def _register(self, topic: str) -> int:
        schema = schema_for_topic(topic)  # ValueError for unknown topics
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            channel_id = self._channel_ids.get(topic)
            if channel_id is not None:
                return channel_id
            title = schema["title"]
            schema_id = self._schema_ids.get(title)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=title,
                    encoding="jsonschema",
                    data=json.dumps(schema, ensure_ascii=False).encode("utf-8"),
                )
                self._schema_ids[title] = schema_id
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
            self._channel_ids[topic] = channel_id
            return channel_id

    # -- the rest -------------------------------------------------------------

    def add_metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """Write a metadata record now (e.g. ``hapticlab.calibration`` once the sensor reported it)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"recording {self.path} is closed")
            self._writer.add_metadata(str(name), _metadata_strings(values))

    def flush(self) -> None:
        """Finish the chunk in progress and hand everything written so far to the OS."""
        with self._lock:
            if self._closed:
                return
            self._writer.flush()
            self._next_flush = _monotonic() + self.flush_interval_s

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Write ``summary`` (if given) as ``hapticlab.summary``, finish the file. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                if summary is not None:
                    values = dict(summary)
                    values.setdefault("end_time", _utc_now_iso())
                    values.setdefault("messages_written", self._messages_written)
                    self._writer.add_metadata(SUMMARY_METADATA, _metadata_strings(values))
                self._writer.finish()
                self._file.flush()
            finally:
                self._file.close()

    @property
    def messages_written(self) -> int:
        """Number of messages recorded so far."""
        return self._messages_written

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def topics(self) -> list[str]:
        """Topics that have a channel in this recording so far."""
        return list(self._channel_ids)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"Recorder({str(self.path)!r}, {state}, {self._messages_written} messages)"


def _mcap_version() -> str:
    try:
        from importlib.metadata import version

        return version("mcap")
    except Exception:  # pragma: no cover
        return "unknown"


# --------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------


def _recover_hint(path: Path) -> str:
    return f"run `hapticlab recover {path} -o FIXED.mcap` to salvage it"


def _truncated(path: Path) -> RecordingError:
    return RecordingError(
        f"{path} is truncated (no MCAP footer; the writer probably died): {_recover_hint(path)}"
    )


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


@dataclass
class Recording:
    """A recording read into memory.

    Attributes:
        path: the file.
        metadata: metadata record name -> {key: string value} (records with the
            same name are merged, later keys win).
        topics: topic -> [(log_time_ns, decoded message)], in log-time order.
        schemas: topic -> its JSON schema (decoded).
    """

    path: Path
    metadata: dict[str, dict[str, str]]
    topics: dict[str, list[tuple[int, dict[str, Any]]]]
    schemas: dict[str, dict[str, Any]] = _dc_field(default_factory=dict)

    @property
    def topic_names(self) -> list[str]:
        """Topics with at least one message, sorted."""
        return sorted(t for t, msgs in self.topics.items() if msgs)

    def __contains__(self, topic: object) -> bool:
        return bool(self.topics.get(topic))  # type: ignore[arg-type]

    def _msgs(self, topic: str) -> list[tuple[int, dict[str, Any]]]:
        try:
            return self.topics[topic]
        except KeyError:
            present = ", ".join(self.topic_names)
            raise KeyError(f"topic {topic!r} is not in {self.path}; present: {present}") from None

    def messages(self, topic: str) -> list[dict[str, Any]]:
        """The decoded messages of ``topic``."""
        return [m for _, m in self._msgs(topic)]

    def t_ns(self, topic: str) -> np.ndarray:
        """(N,) int64 log times of ``topic``, ns."""
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
        summary = reader.get_summary()
    except Exception as exc:
        f.close()
        raise _damaged(path, exc) from None
    return f, reader, summary


def _iter_raw(
    path: Path, topics: Iterable[str] | str | None, log_time_order: bool = True
) -> Iterator[tuple[Channel, Message]]:
    f, reader, _ = _open_reader(path)
    with f:
        topic_list = [topics] if isinstance(topics, str) else (list(topics) if topics is not None else None)
        try:
            for _schema, channel, message in reader.iter_messages(topics=topic_list, log_time_order=log_time_order):
                yield channel, message
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

    ``topics`` limits the topics read (chunks without them are skipped).
    Raises :class:`RecordingError` for a file that is not MCAP or is truncated.
    """
    path = Path(path)
    _check_mcap(path)  # fail here, not at the first next()
    return _decode(_iter_raw(path, topics))


def _decode(raw: Iterator[tuple[Channel, Message]]) -> Iterator[tuple[str, int, dict[str, Any]]]:
    loads = json.loads
    for channel, message in raw:
        yield channel.topic, message.log_time, loads(message.data)


def read_recording(path: str | os.PathLike[str], topics: Iterable[str] | str | None = None) -> Recording:
    """Read a recording into memory (optionally only some ``topics``).

    Raises :class:`RecordingError` (a ``ValueError``) with a one-line message
    when the file is not MCAP, or is truncated or damaged (the message says to
    run ``hapticlab recover``).
    """
    path = Path(path)
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
    out: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    loads = json.loads
    # File order (no global time-ordered merge, which costs more than the decoding), with the
    # cyclic GC paused while building many small containers; each topic is sorted afterwards.
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        for channel, message in _iter_raw(path, topics, log_time_order=False):
            lst = out.get(channel.topic)
            if lst is None:
                lst = out[channel.topic] = []
            lst.append((message.log_time, loads(message.data)))
    finally:
        if gc_was_enabled:
            gc.enable()
    for lst in out.values():
        if any(lst[i][0] > lst[i + 1][0] for i in range(len(lst) - 1)):
            lst.sort(key=lambda item: item[0])  # stable: equal times keep file order
    return Recording(path=path, metadata=metadata, topics=out, schemas=schemas)


# --------------------------------------------------------------------------
# Recovery
# --------------------------------------------------------------------------

_KNOWN_OPCODES = {int(op) for op in Opcode}


def recover(broken_path: str | os.PathLike[str], fixed_path: str | os.PathLike[str]) -> dict[str, Any]:
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
    the input had a proper end, "last_t_ns": latest log time or None}``.
    Raises :class:`RecordingError` when the input is not an MCAP file.
    """
    src = Path(broken_path)
    dst = Path(fixed_path)
    if src.resolve() == dst.resolve():
        raise ValueError("recover: the output must be a different file than the broken input")
    size = src.stat().st_size
    tmp = dst.with_name(dst.name + ".partial")
    dst.parent.mkdir(parents=True, exist_ok=True)

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
            raise RecordingError(
                f"{src} is not an MCAP file (bad magic bytes at the start): nothing to recover"
            )
        with open(tmp, "wb") as out_file:
            writer = Writer(out_file, compression=CompressionType.ZSTD)
            started = False

            def start(profile: str = "") -> None:
                nonlocal started
                if not started:
                    writer.start(profile=profile, library=f"hapticlab-recover/{_hapticlab_version()}")
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
                writer.add_message(
                    new_id, message.log_time, message.data, message.publish_time, message.sequence
                )
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
                        writer.add_attachment(
                            att.create_time, att.log_time, att.name, att.media_type, att.data
                        )
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
            start()
            writer.add_metadata(
                RECOVERED_METADATA,
                _metadata_strings(
                    {
                        "source": str(src),
                        "recovered_at": _utc_now_iso(),
                        "messages": stats["messages"],
                        "lost_tail_bytes": stats["lost_tail_bytes"],
                        "corrupt_chunks": stats["corrupt_chunks"],
                        "orphan_messages": stats["orphan_messages"],
                        "complete": stats["complete"],
                    }
                ),
            )
            writer.finish()
    os.replace(tmp, dst)
    return stats
