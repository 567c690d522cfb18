"""A recording's metadata records: the ``hapticlab.session`` record's defaults, and every value as a string.

MCAP metadata values are strings: a string is kept, anything else is
JSON-encoded (numpy arrays and scalars as their values, paths as strings, sets
sorted). :func:`session_record` fills in what every session records about
itself unless the caller gave it: ``format_version``, ``hapticlab_version``,
``git_revision`` (where known), ``start_time`` (UTC, ISO 8601),
``start_monotonic_ns`` (the session clock at that instant), ``clock_offset_ns``
(Unix time minus the session clock, ns: a message's log time is its session
time plus this), ``python`` and ``mcap``. :func:`clock_offset` reads the
offset back (0 for a file from before it: log times on the session clock).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
import time
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.version import __version__


def json_default(obj: Any) -> Any:
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


_encode_meta = json.JSONEncoder(separators=(",", ":"), allow_nan=True, default=json_default).encode


def metadata_strings(values: Mapping[str, Any]) -> dict[str, str]:
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
            ["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=2.0, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return None
    rev = result.stdout.strip()
    return rev if result.returncode == 0 and rev else None


def utc_now_iso() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def mcap_version() -> str:
    try:
        from importlib.metadata import version

        return version("mcap")
    except Exception:  # pragma: no cover
        return "unknown"


def session_record(
    given: Mapping[str, Any], start_monotonic_ns: int, format_version: int, clock_offset_ns: int
) -> dict[str, str]:
    """The ``hapticlab.session`` record: ``given`` with the defaults every session records filled in, as strings;
    ``clock_offset_ns`` always (the offset the log times were written with)."""
    session = dict(given)
    session.setdefault("format_version", format_version)
    session.setdefault("hapticlab_version", __version__)
    rev = git_revision()
    if rev is not None:
        session.setdefault("git_revision", rev)
    session.setdefault("start_time", utc_now_iso())
    session.setdefault("start_monotonic_ns", start_monotonic_ns)
    session["clock_offset_ns"] = clock_offset_ns
    session.setdefault("python", platform.python_version())
    session.setdefault("mcap", mcap_version())
    return metadata_strings(session)


CLOCK_OFFSET_MAX = 1 << 62
"""The largest clock offset a recording may state, ns (Unix time is about 2^60.6 ns; a log time stays under 2^64)."""


def wall_clock_offset() -> int:
    """Unix time minus the monotonic clock now, ns (``time.time_ns() - time.monotonic_ns()``, the monotonic clock
    read on both sides of the wall clock and averaged, so the pair is read at one instant to within a microsecond)."""
    before = time.monotonic_ns()
    wall = time.time_ns()
    after = time.monotonic_ns()
    return wall - (before + after) // 2


def clock_offset(session: Mapping[str, str]) -> int:
    """The ``clock_offset_ns`` of a ``hapticlab.session`` record (its string values as recorded), ns; 0 when absent
    (a file written before log times were Unix time: its log times are the session clock's). ``ValueError`` for a
    value that is not an integer in [0, 2^62) ns."""
    raw = session.get("clock_offset_ns")
    if raw is None:
        return 0
    try:
        value = int(raw)
    except (TypeError, ValueError):
        raise ValueError(f"clock_offset_ns: must be an integer (ns), got {str(raw)[:40]!r}") from None
    if not 0 <= value < CLOCK_OFFSET_MAX:
        raise ValueError(f"clock_offset_ns: must be in [0, 2^62) ns, got {value}")
    return value


def clock_offset_from_start(session: Mapping[str, str]) -> int | None:
    """The clock offset a ``hapticlab.session`` record without ``clock_offset_ns`` implies, ns: its ``start_time``
    (UTC, ms) minus its ``start_monotonic_ns``, read a moment apart (ms off); None when either is missing or bad.
    For a copy of a file from before the offset (``replay -o``): its log times then fall on its own dates."""
    try:
        start = _dt.datetime.fromisoformat(session["start_time"])
        mono = int(session["start_monotonic_ns"])
    except (KeyError, TypeError, ValueError):
        return None
    if start.tzinfo is None:
        return None
    offset = round(start.timestamp() * 1e3) * 1_000_000 - mono
    return offset if 0 <= offset < CLOCK_OFFSET_MAX else None
