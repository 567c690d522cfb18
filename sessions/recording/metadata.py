"""A recording's metadata records: the ``hapticlab.session`` record's defaults, and every value as a string.

MCAP metadata values are strings: a string is kept, anything else is
JSON-encoded (numpy arrays and scalars as their values, paths as strings, sets
sorted). :func:`session_record` fills in what every session records about
itself unless the caller gave it: ``format_version``, ``hapticlab_version``,
``git_revision`` (where known), ``start_time`` (UTC, ISO 8601),
``start_monotonic_ns`` (the session clock at that instant), ``python`` and
``mcap``.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import subprocess
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


def session_record(given: Mapping[str, Any], start_monotonic_ns: int, format_version: int) -> dict[str, str]:
    """The ``hapticlab.session`` record: ``given`` with the defaults every session records filled in, as strings."""
    session = dict(given)
    session.setdefault("format_version", format_version)
    session.setdefault("hapticlab_version", __version__)
    rev = git_revision()
    if rev is not None:
        session.setdefault("git_revision", rev)
    session.setdefault("start_time", utc_now_iso())
    session.setdefault("start_monotonic_ns", start_monotonic_ns)
    session.setdefault("python", platform.python_version())
    session.setdefault("mcap", mcap_version())
    return metadata_strings(session)
