"""An MCAP session recording read into a :class:`~.stream.Stream`: the wrench samples, each with the
orientation (and position, when every pose has one) interpolated at its own time.

The pose topic is read whole as arrays, then the wrench topic chunk by chunk.
A message without a field the stream needs, or with a field of the wrong
shape, is a :class:`~.mcapfile.RecordingError` naming the file, the topic, the
message and the field (:func:`message_field`).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from itertools import chain, islice
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.aligner import orientation_at, position_at
from hapticlab.core.frames import matrix_from_quat_wxyz
from hapticlab.core.types import AlignedSamples
from hapticlab.sessions.recording.mcapfile import RecordingError
from hapticlab.sessions.recording.messages import iter_messages
from hapticlab.sessions.recording.reader import open_recording
from hapticlab.sessions.recording.stream import Stream, off_unit

WRENCH_TOPIC = "/sensor/wrench"
POSE_TOPIC = "/kinematics/pose"
_REQUIRED = object()


def message_field(
    source: str,
    topic: str,
    messages: list[tuple[int, Any]],
    name: str,
    width: int | None,
    dtype: Any = float,
    default: Any = _REQUIRED,
    first: int = 0,
) -> np.ndarray:
    """Field ``name`` of each ``(t_ns, message)`` as an (n, width) array ((n,) for ``width`` None).

    JSON null (a recorded NaN) becomes NaN. ``default`` stands in for a
    missing field (a callable gets the message's index in the topic);
    without one a missing field is an error. A message that is not a JSON
    object, lacks the field or holds something else than ``width`` numbers is
    a :class:`RecordingError` naming ``source``, the topic, the message (1 =
    the topic's first; ``first`` is the index of ``messages[0]``) and the field.
    """
    shape = (len(messages),) if width is None else (len(messages), width)

    def pick(k: int, m: Any) -> Any:
        if default is _REQUIRED:
            return m[name]
        return m.get(name, default(first + k) if callable(default) else default)

    try:
        out = np.array([pick(k, m) for k, (_, m) in enumerate(messages)], dtype=dtype)
        if out.shape == shape:
            return out
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        pass
    what = "a number" if width is None else f"{width} numbers"
    for k, (_, m) in enumerate(messages):
        where = f"{source}: {topic} message {first + k + 1}"
        if not isinstance(m, dict):
            raise RecordingError(f"{where} is not a JSON object (got {_short(m)})")
        if name not in m and default is _REQUIRED:
            raise RecordingError(f"{where} has no field {name!r} (fields: {', '.join(map(str, m)) or 'none'})")
        value = pick(k, m)
        try:
            ok = np.array(value, dtype=dtype).shape == shape[1:]
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise RecordingError(f"{where}, field {name!r}: expected {what}, got {_short(value)}")
    raise AssertionError("unreachable: the messages converted one by one")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _messages(path: Path, topic: str) -> Iterator[tuple[int, Any]]:
    """``(t_ns, message)`` of one topic in time order; a message that is not JSON is a RecordingError."""
    k = 0
    try:
        # k is read by the except below: the message that broke
        for k, (_, t_ns, message) in enumerate(iter_messages(path, topic), start=1):  # noqa: B007
            yield t_ns, message
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path.name}: {topic} message {k + 1} is not valid JSON ({exc})") from None


def _batches(messages: Iterator[tuple[int, Any]], rows: int) -> Iterator[list[tuple[int, Any]]]:
    while batch := list(islice(messages, rows)):
        yield batch


def _missing_topic(path: Path, topic: str) -> RecordingError:
    present = ", ".join(sorted(open_recording(path).topics)) or "none"
    return RecordingError(
        f"{path.name}: no {topic} messages (topics: {present}); offline tools need {WRENCH_TOPIC} and {POSE_TOPIC}"
    )


def _poses(path: Path, rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The whole pose stream as arrays: (M,) t_ns, (M, 4) quat_BE, (M, 3) p_BoEo_B or None (not in every pose)."""
    name = path.name
    t_parts, quat_parts, p_parts = [], [], []
    has_p = True
    done = 0
    for batch in _batches(_messages(path, POSE_TOPIC), rows):
        t_parts.append(np.array([t for t, _ in batch], dtype=np.int64))
        quat = message_field(name, POSE_TOPIC, batch, "quat_BE", 4, first=done)
        norm = np.linalg.norm(quat, axis=1)
        if (k := off_unit(norm)) is not None:  # NaN rows pass: they make samples unusable
            raise RecordingError(
                f"{name}: {POSE_TOPIC} message {done + k + 1}, field 'quat_BE': not a unit "
                f"quaternion (norm {norm[k]:.6g})"
            )
        quat_parts.append(quat)
        has_p = has_p and all(isinstance(m, dict) and m.get("p_BoEo_B") is not None for _, m in batch)
        if has_p:
            p_parts.append(message_field(name, POSE_TOPIC, batch, "p_BoEo_B", 3, first=done))
        done += len(batch)
    if not done:
        raise _missing_topic(path, POSE_TOPIC)
    return np.concatenate(t_parts), np.concatenate(quat_parts), np.concatenate(p_parts) if has_p else None


def iter_mcap(path: Path, rows: int) -> Iterator[Stream]:
    """An MCAP session recording read topic by topic: the poses as arrays, then the wrench stream
    chunk by chunk, each sample with the orientation interpolated at its own time."""
    name = path.name
    wrenches = _messages(path, WRENCH_TOPIC)
    first = next(wrenches, None)
    if first is None:
        raise _missing_topic(path, WRENCH_TOPIC)
    pose_t, quat, p = _poses(path, rows)
    period = int(np.median(np.diff(pose_t))) if len(pose_t) > 1 else 0
    t0 = first[0]
    done = 0
    for batch in _batches(chain([first], wrenches), rows):
        t_ns = np.array([t for t, _ in batch], dtype=np.int64)
        force_S = message_field(name, WRENCH_TOPIC, batch, "force_S", 3, first=done)
        torque_S = message_field(name, WRENCH_TOPIC, batch, "torque_S", 3, first=done)
        status = message_field(name, WRENCH_TOPIC, batch, "status", None, np.int64, default=0, first=done)
        seq = message_field(name, WRENCH_TOPIC, batch, "seq", None, np.int64, default=lambda k: k, first=done)
        quat_BE, stale = orientation_at(t_ns, pose_t, quat, period)
        R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
        p_BoEo_B = None if p is None else position_at(t_ns, pose_t, p, period)
        samples = AlignedSamples(t_ns, force_S, torque_S, R_EB, seq, status, stale, quat_BE, p_BoEo_B)
        done += len(batch)
        yield Stream((t_ns - t0) * 1e-9, samples, [], str(path))
