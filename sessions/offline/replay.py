"""``hapticlab replay``: re-run a recording through another estimator and compare.

The recorded sensor and pose streams are aligned offline (every sample
interpolated between poses) and fed to the named estimator exactly as a session
would; the new MCAP holds everything the original did plus the new estimator's
topic, at the original's log times (its ``clock_offset_ns``), and a table
compares every estimator in it. :func:`replay_folder` does it
for every recording in a folder, in parallel (Dask: ``folders.py``).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.host.interfaces import cov_diag_of, params_of
from hapticlab.core.host.registry import Registry
from hapticlab.core.types import first_true
from hapticlab.sessions.offline.compensate import estimator_options, run_estimator
from hapticlab.sessions.offline.folders import FolderError, FolderRun, map_recordings, recordings_in
from hapticlab.sessions.offline.metrics import max_ae, rms, scored_rows
from hapticlab.sessions.output import atomic_output, check_output
from hapticlab.sessions.recording import Recorder, RecordingError, read_recording, schema_for_topic
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.mcapimport import message_field
from hapticlab.sessions.recording.metadata import clock_offset_from_start
from hapticlab.sessions.recording.schemas import SESSION_METADATA


def replay(
    recording_path: str | Path,
    estimator_name: str,
    out_path: str | Path | None = None,
    overrides: list[str] | None = None,
    registry: Registry | None = None,
    force: bool = False,
) -> dict[str, Any]:
    """Replay a recording through ``estimator_name``; returns the comparison (and writes ``out_path``).

    ``out_path`` is checked before the work (an existing file is refused unless
    ``force``) and written whole or not at all (``sessions.output``).
    """
    registry = registry if registry is not None else Registry()
    recording_path = Path(recording_path)
    options = estimator_options(overrides or [])
    estimator_name = options.pop("name", estimator_name)
    if out_path is not None:
        out_path = check_output(out_path, force, label="-o", inputs=[recording_path], role="recording")
    estimator = registry.create("estimator", estimator_name, options, where="estimator")
    stream = load_stream(recording_path)
    original = _read_all(recording_path)
    if out_path is not None:
        for name in original.topics:
            try:
                schema_for_topic(name)
            except ValueError:
                raise RecordingError(
                    f"{recording_path.name}: topic {name!r} is not a hapticlab topic; replay -o "
                    f"copies every topic and cannot record that one"
                ) from None
    est = run_estimator(stream, estimator)

    label = estimator_name
    while f"/estimator/{label}" in original.topics:
        label += "_replay"
    topic = f"/estimator/{label}"
    flags = {
        "contact_force_S": est.contact_force_S.tolist(),
        "contact_torque_S": est.contact_torque_S.tolist(),
        "contact": est.contact.tolist(),
        "converged_force": est.converged_force.tolist(),
        "converged_torque": est.converged_torque.tolist(),
    }
    comparison = compare(original, stream.samples.t_ns, {topic: est})
    if out_path is not None:
        metadata = {name: dict(values) for name, values in original.metadata.items()}
        session = metadata.setdefault(SESSION_METADATA, {})
        if "clock_offset_ns" not in session and (derived := clock_offset_from_start(session)) is not None:
            session["clock_offset_ns"] = str(derived)  # a file from before the offset: its log times on its dates
        metadata["hapticlab.replay"] = {
            "source": str(recording_path),
            "estimator": estimator_name,
            "topic": topic,
            "options": json.dumps(options),
        }
        with atomic_output(out_path, force, label="-o") as tmp, Recorder(tmp, metadata=metadata) as rec:
            # every original message in time order, then the new estimator's
            for name, messages in original.topics.items():
                for t_ns, message in messages:
                    rec.write(name, t_ns, message)
            n = len(est)
            for i, t_ns in enumerate(stream.samples.t_ns.tolist()):
                rec.write(
                    topic,
                    t_ns,
                    {key: values[i] for key, values in flags.items()}
                    | {
                        "params": params_of(estimator) if i == n - 1 else None,
                        "cov_diag": cov_diag_of(estimator) if i == n - 1 else None,
                    },
                )
    return {
        "topic": topic,
        "estimator": estimator_name,
        "rows": len(est),
        "comparison": comparison,
        "params": params_of(estimator),
    }


def replay_folder(
    folder: str | Path,
    estimator_name: str,
    out_dir: str | Path | None = None,
    overrides: list[str] | None = None,
    force: bool = False,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
) -> FolderRun:
    """:func:`replay` over every recording under ``folder``, in parallel (``folders.map_recordings``).

    With ``out_dir`` each replayed recording is written there at the same relative path;
    every output is checked before the work starts (an existing one is refused unless
    ``force``). Each outcome's value is :func:`replay`'s comparison for that file.
    """
    folder = Path(folder)
    paths = recordings_in(folder)
    if out_dir is not None:
        out_dir = Path(out_dir)
        if out_dir.resolve().is_relative_to(folder.resolve()):
            raise FolderError(f"-o {out_dir}: inside the folder being replayed ({folder}); choose another folder")
        for path in paths:
            out = out_dir / path.relative_to(folder)
            out.parent.mkdir(parents=True, exist_ok=True)
            check_output(out, force, label="-o", inputs=[path], role="recording")
    task = functools.partial(
        _replay_one,
        estimator_name=estimator_name,
        overrides=list(overrides or []),
        force=force,
        folder=folder,
        out_dir=out_dir,
    )
    return map_recordings(
        task,
        paths,
        scheduler=scheduler,
        workers=workers,
        progress=progress,
        description=f"replaying through {estimator_name}",
    )


def _replay_one(
    path: Path, estimator_name: str, overrides: list[str], force: bool, folder: Path, out_dir: Path | None
) -> dict[str, Any]:
    """One file of :func:`replay_folder` (in a worker process)."""
    out = None
    if out_dir is not None:
        out = out_dir / path.relative_to(folder)
        out.parent.mkdir(parents=True, exist_ok=True)
    result = replay(path, estimator_name, out, overrides, force=force)
    result.pop("params")
    return result


def _read_all(path: Path):
    """The whole recording; a message that is not JSON is a RecordingError naming the file."""
    try:
        return read_recording(path)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{path.name}: a message is not valid JSON ({exc})") from None


def _recorded(original, topic: str, t_ns: np.ndarray) -> dict[str, np.ndarray] | None:
    """A recorded estimator topic as arrays aligned to the wrench sample times."""
    messages = original.topics.get(topic, [])
    if not messages:
        return None
    source = original.path.name
    force = message_field(source, topic, messages, "contact_force_S", 3)  # null (a recorded NaN) becomes NaN
    contact = message_field(source, topic, messages, "contact", None)
    converged = message_field(source, topic, messages, "converged_force", None)
    index = {t: k for k, (t, _) in enumerate(messages)}
    rows = np.array([index.get(int(t), -1) for t in t_ns], dtype=np.int64)
    seen = rows >= 0

    def pick(values: np.ndarray, empty: float) -> np.ndarray:
        return np.where(seen.reshape(-1, *([1] * (values.ndim - 1))), values[np.maximum(rows, 0)], empty)

    return {
        "contact_force_S": pick(force, np.nan),
        "contact": pick(contact, 0.0).astype(bool),
        "converged_force": pick(converged, 0.0).astype(bool),
        "seen": seen,
    }


def compare(original, t_ns: np.ndarray, new: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per estimator: per-axis RMS and Max AE on no-contact samples after convergence, convergence, agreement.

    "No contact" means neither the recording's primary estimator nor the one
    scored flagged the sample; contact agreement is against the primary's flags.
    """
    primary_name = original.metadata.get("hapticlab.session", {}).get("estimator")
    series: dict[str, dict[str, np.ndarray]] = {}
    for topic in sorted(t for t in original.topics if t.startswith("/estimator/")):
        data = _recorded(original, topic, t_ns)
        if data is not None:
            series[topic] = data
    for topic, est in new.items():
        series[topic] = {
            "contact_force_S": est.contact_force_S,
            "contact": est.contact,
            "converged_force": est.converged_force,
            "seen": np.isfinite(est.contact_force_S).all(1),
        }
    primary = series.get(f"/estimator/{primary_name}") if primary_name else None
    out = {}
    for topic, data in series.items():
        conv = data["converged_force"]
        first = first_true(conv)
        entry: dict[str, Any] = {"converged_force_at": first}
        if first is not None:
            rows = scored_rows(first, data["contact_force_S"], data["contact"]) & data["seen"]
            if primary is not None:
                rows &= ~primary["contact"]
            f = data["contact_force_S"][rows]
            entry["rms_force_S"] = rms(f).tolist() if len(f) else None
            entry["max_ae_force_S"] = max_ae(f).tolist() if len(f) else None
        if primary is not None:
            both = data["seen"] & primary["seen"]
            entry["contact_agreement_pct"] = 100.0 * float(np.mean(data["contact"][both] == primary["contact"][both]))
        out[topic] = entry
    return out
