"""Block messages (formats 2 and 3: one message per block of samples on a sensor-rate topic) taken apart.

A block comes out as its samples' ``(t_ns, message)`` (:func:`expand_block`: exactly
what format 1 recorded one by one) or as columns (:func:`as_columns`,
:func:`cdr_block_field`: numpy arrays, NaN for every non-finite float);
:func:`stack` turns one JSON field of many messages into one array.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.recording.cdr import listed
from hapticlab.sessions.recording.mcapfile import RecordingError
from hapticlab.sessions.recording.schemas import BLOCK_LAST_SAMPLE_FIELDS, ESTIMATOR_TOPIC_PREFIX


def block_times(blocks: list[dict[str, Any]]) -> np.ndarray:
    if blocks and isinstance(blocks[0]["t_ns"], np.ndarray):
        return np.concatenate([b["t_ns"] for b in blocks]).astype(np.int64, copy=False)
    times = [t for b in blocks for t in b["t_ns"]]
    return np.fromiter(times, dtype=np.int64, count=len(times))


def cdr_block_field(topic: str, blocks: list[dict[str, Any]], name: str) -> np.ndarray:
    """A field of CDR blocks concatenated: the recorded dtype (int64, bool, float with NaN for every
    non-finite value); float with NaN where a block lacks the field (as ``stack`` does for JSON)."""
    parts: list[Any] = [b.get(name) for b in blocks]  # arrays, None where a block lacks the field
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


def check_block(path: Path, topic: str, log_time: int, block: Any) -> None:
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


def expand_block(topic: str, block: dict[str, Any]) -> list[tuple[int, dict[str, Any]]]:
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


def stack(values: list[Any]) -> np.ndarray:
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


def as_columns(block: dict[str, Any]) -> dict[str, Any]:
    """A block message with every per-sample column as a numpy array (JSON lists stacked, null → NaN)."""
    out: dict[str, Any] = {}
    for key, column in block.items():
        # the last sample's fields as they are; CDR columns as recorded (a non-finite float NaN or ±inf)
        if key in BLOCK_LAST_SAMPLE_FIELDS or isinstance(column, np.ndarray):
            out[key] = column
        else:
            out[key] = np.asarray(column, dtype=np.int64) if key == "t_ns" else stack(column)
    return out
