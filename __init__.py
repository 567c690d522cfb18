"""hapticlab: plugin-based haptic teleoperation for robotic-surgery training.

The Python API (``docs/api.md``; the command line is a thin shell over it)::

    import hapticlab
    path = hapticlab.run("demo", settings={"session.duration": 3, "session.realtime": False})
    rec = hapticlab.open_recording(path)
    est = hapticlab.make_estimator("kalman", noise_force="auto")
    out = hapticlab.compensate(path, est)

The package is laid out by data flow: ``hapticlab.core`` (hookspecs, plugin
host, contracts, data types, frames, estimator math; no I/O),
``hapticlab.plugins`` (built-in sensors, kinematics, estimators, haptic
outputs, effects, the simulated world) and ``hapticlab.sessions`` (by job:
``live``, ``recording``, ``offline``, ``bench``, ``discrepancy``, ``cli``).

What the functions return and raise is exported here too (``Recording``,
``Estimates``, ``Stream``, ``Estimator``, ``SessionError``, ``RecordingError``),
imported on first use, so ``import hapticlab`` stays light.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hapticlab import numba_cache
from hapticlab.core.lazy import lazy_exports
from hapticlab.core.version import __version__ as __version__

numba_cache.choose(Path(__file__).parent)  # before any kernel is compiled (numba_cache.py says why)

if TYPE_CHECKING:
    from hapticlab.core.host.interfaces import Estimator
    from hapticlab.core.types import Estimates
    from hapticlab.sessions.live.status import SessionError
    from hapticlab.sessions.recording.mcapfile import RecordingError
    from hapticlab.sessions.recording.reader import Recording
    from hapticlab.sessions.recording.stream import Stream

__all__ = [
    "Estimates",
    "Estimator",
    "Recording",
    "RecordingError",
    "SessionError",
    "Stream",
    "compensate",
    "get_plugins",
    "load_session",
    "make_estimator",
    "open_recording",
    "run",
]

_TYPES = {
    "Estimates": "hapticlab.core.types",
    "Estimator": "hapticlab.core.host.interfaces",
    "Recording": "hapticlab.sessions.recording.reader",
    "RecordingError": "hapticlab.sessions.recording.mcapfile",
    "SessionError": "hapticlab.sessions.live.status",
    "Stream": "hapticlab.sessions.recording.stream",
}
"""The exported types, by the module that defines them (imported on first use: the sessions import numba)."""


__getattr__ = lazy_exports(__name__, _TYPES)


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


def load_session(
    session: str | Path | Mapping[str, Any] = "demo", settings: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """A session's config: a preset name, a TOML path or a dict, with ``settings`` applied.

    ``settings`` maps dotted keys to values, as ``--set`` does on the command
    line: ``{"session.duration": 3, "estimator.name": "kalman"}``.
    """
    from hapticlab.sessions.config import apply_settings, load_config

    if isinstance(session, Mapping):
        config = dict(session)
    else:
        config, _ = load_config(str(session))
    return apply_settings(config, dict(settings or {}))


def run(
    session: str | Path | Mapping[str, Any] = "demo",
    settings: Mapping[str, Any] | None = None,
    *,
    out: str | Path | None = None,
) -> Path:
    """Run a session to its end and return the path of its recording (an MCAP file).

    ``session`` is a preset name (``"demo"``), a TOML path or a config dict;
    ``settings`` dotted keys as in :func:`load_session`; ``out`` the recording's
    path (default ``recordings/<name>-<time>.mcap``, never an existing file).
    A device or estimator that fails raises :class:`SessionError`; its
    ``result.path`` is the complete recording.
    """
    from hapticlab.sessions.live import build_session, run_session

    return run_session(build_session(load_session(session, settings)), out=out).path


def open_recording(path: str | os.PathLike[str]) -> Recording:
    """Open a recording: ``metadata``, ``events``, ``topic_names``, ``messages(topic)`` yielding
    ``(t_ns, dict)``, and arrays: ``wrench()``, ``poses()``, ``estimates(name)``; topics are read on demand.

    Raises ``RecordingError`` (one line) for a file that is not MCAP, or is truncated or damaged."""
    from hapticlab.sessions.recording import open_recording as _open

    return _open(path)


def make_estimator(name: str, **options: Any) -> Estimator:
    """A registered estimator built with ``options`` (checked against its signature, as a session's
    ``[estimator]`` table is): ``make_estimator("rls", force_threshold=0.6)``."""
    from hapticlab.core.host.registry import Registry

    return Registry().create("estimator", name, options, where="estimator")


def compensate(stream_or_path: str | os.PathLike[str] | Stream, estimator: str | Estimator = "rls") -> Estimates:
    """Run an estimator over a recording (a CSV or MCAP path, or a loaded ``Stream``), offline.

    ``estimator`` is a name (built with its defaults) or an estimator object
    (e.g. from :func:`make_estimator`). Returns the ``Estimates``, one row per
    input row (rows the estimator could not use carry NaN).
    """
    from hapticlab.sessions.offline.compensate import run_estimator
    from hapticlab.sessions.recording.loader import load_stream
    from hapticlab.sessions.recording.stream import Stream

    stream = stream_or_path if isinstance(stream_or_path, Stream) else load_stream(stream_or_path)
    if isinstance(estimator, str):
        estimator = make_estimator(estimator)
    return run_estimator(stream, estimator)


def get_plugins() -> list[dict[str, str]]:
    """Every registered plugin: ``{"kind", "name", "origin"}``, by kind then name."""
    from hapticlab.core.host.registry import Registry

    return [{"kind": e.kind, "name": e.name, "origin": e.origin} for e in Registry().entries()]
