"""One recorded session reviewed: who and what, the streams' health, convergence, contacts, the paper's table.

:func:`review` reads the recording once, streaming (``recording.columnar``:
a few chunks at a time as columns; ``iter_blocks``, a message at a time, for
older or unfinished files: ``reading``), so memory stays bounded whatever the length: the
samples are gathered into chunks of :data:`CHUNK_ROWS` and each chunk is
folded into the running figures of ``figures.py`` (sums with Chan's merge
for the standard deviations, a contact state machine, time-binned envelopes
for the plots), then dropped.

What an instructor grades by comes from the primary estimator's contact
estimate (the force on the tissue, ``‖contact_force_S‖``, N):

* **contacts**: runs of the estimator's contact flag, two runs less than
  :data:`~.figures.MERGE_GAP_S` apart counted as one; each with its start, duration,
  peak and mean force;
* **time over the force limit**: how long ‖contact force‖ was above the limit
  (``force_limit``, N), summed over samples (each sample one sensor period).

The paper's table (``metrics.error_stats``: MAE, Max AE, Std before and after,
MAE compensation %) is scored on every estimator's no-contact samples from its
convergence on (force axes from the force stage's, torque axes from the torque
stage's), "before" being the raw aligned reading of the same sample.
"""

from __future__ import annotations

import math
import os
from collections import deque
from typing import Any

import numpy as np

from hapticlab.core.types import STATUS_OK, Event
from hapticlab.sessions.recording import ESTIMATOR_TOPIC_PREFIX, RecordingError, open_recording
from hapticlab.sessions.recording.columnar import can_read
from hapticlab.sessions.recording.mcapfile import file_stats
from hapticlab.sessions.review.figures import ContactFold, Envelope, EstimatorFold
from hapticlab.sessions.review.reading import file_batches, join_raw
from hapticlab.sessions.review.session import (  # noqa: F401  (re-exported: where they were first)
    DEFAULT_FORCE_LIMIT_N,
    ROUTINE_EVENTS,
    Series,
    SessionReview,
    faults,
    haptic_on_runs,
)
from hapticlab.sessions.review.skill_fold import SkillFold
from hapticlab.sessions.review.skill_names import KEYS
from hapticlab.sessions.tasks.scoring import score

CHUNK_ROWS = 16384
"""Samples gathered before they are folded into the running figures (memory: a few MB, whatever the file)."""


def review(
    path: str | os.PathLike[str], force_limit: float | None = None, plots: bool = True, progress=None, fast: bool = True
) -> SessionReview:
    """Review one recording (streamed; memory bounded whatever its length).

    Args:
        path: the session's ``.mcap``.
        force_limit: the contact force limit to count time above, N; None: the session's task's
            (``task.force_limit``), else :data:`DEFAULT_FORCE_LIMIT_N`.
        plots: also gather what the plots draw (the haptic commands are read only then).
        progress: ``progress(done_fraction)`` called as the file is read (a progress bar), or None.
        fast: read the file a chunk at a time as columns (``recording.columnar``; a finished format-3
            file) rather than a message at a time (``iter_blocks``, every format): the same figures
            (tested), several times faster.

    Raises ``RecordingError`` (a ``ValueError``, one line) for a file that is not a
    hapticlab recording, is truncated or has no estimator.
    """
    if force_limit is not None and not force_limit > 0:
        raise ValueError(f"force limit: must be > 0 N, got {force_limit!r}")
    rec = open_recording(path)
    config = rec.meta("hapticlab.session", "config", {}) or {}
    if not isinstance(config, dict):
        config = {}
    session = config.get("session", {})
    recorded = config.get("task")
    task: dict[str, Any] = recorded if isinstance(recorded, dict) else {}
    if force_limit is None:
        force_limit = float(task.get("force_limit") or DEFAULT_FORCE_LIMIT_N)
    estimator = rec.meta("hapticlab.session", "estimator", "") or ""
    names = [t[len(ESTIMATOR_TOPIC_PREFIX) :] for t in rec.topic_names if t.startswith(ESTIMATOR_TOPIC_PREFIX)]
    if "/aligned/sample" not in rec.topic_names or not names:
        raise RecordingError(
            f"{rec.path}: no /aligned/sample or /estimator/<name> topic: not a session recording hapticlab can review"
        )
    estimator = estimator if estimator in names else names[0]
    stats = file_stats(rec.path)
    t0, t1, counts = stats.start_ns, stats.end_ns, stats.counts
    duration = (t1 - t0) / 1e9
    sensor_rate = float(config.get("sensor", {}).get("rate_hz") or 0.0)
    period_s = 1.0 / sensor_rate if sensor_rate > 0 else 0.0

    folds = {name: EstimatorFold(name, t0) for name in names}
    contact: ContactFold | None = None  # built once the sensor period is known
    band = task.get("band") if task.get("name") == "retraction" else None
    marks = int(task.get("mark_button", -1)) if task.get("name") == "palpation" else -1
    skill = SkillFold(t0, force_limit, band, marks)
    series = Series(
        Envelope(t0, t1, 6), Envelope(t0, t1, 6), Envelope(t0, t1, 1), Envelope(t0, t1, 2) if plots else None
    )
    events: list[Event] = []
    pending: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name in names}
    pending_rows = dict.fromkeys(names, 0)
    aligned_chunk: list[dict[str, np.ndarray]] = []
    aligned_rows = 0
    # counts (int), and the last sequence number and first and last stamps (int, None before the first sample)
    health: dict[str, Any] = {"samples": 0, "lost": 0, "bad": 0, "last_seq": None, "first_t": None, "last_t": None}
    commands: list[dict[str, np.ndarray]] = []
    command_rows = 0
    port = {"max_J": -math.inf, "damped": 0, "ticks": 0}  # /haptic/passivity, folded as it comes
    if plots and "/haptic/passivity" in rec.topic_names:
        series.passivity = Envelope(t0, t1, 2)

    def fold_aligned() -> None:
        nonlocal aligned_rows
        if not aligned_chunk:
            return
        seq = np.concatenate([b["seq"] for b in aligned_chunk]).astype(np.int64)
        status = np.concatenate([b["status"] for b in aligned_chunk]).astype(np.int64)
        f = np.concatenate([b["force_S"] for b in aligned_chunk])
        t = np.concatenate([b["t_ns"] for b in aligned_chunk])
        if health["last_seq"] is not None:
            seq = np.concatenate(([health["last_seq"]], seq))
        steps = np.diff(seq)
        health["lost"] += int(np.clip(steps - 1, 0, None).sum())
        health["last_seq"] = int(seq[-1])
        health["bad"] += int(((status != STATUS_OK) | ~np.isfinite(f).all(1)).sum())
        health["samples"] += len(t)
        health["first_t"] = health["first_t"] if health["first_t"] is not None else int(t[0])
        health["last_t"] = int(t[-1])
        aligned_chunk.clear()
        aligned_rows = 0

    def fold_estimator(name: str) -> None:
        nonlocal contact
        blocks = pending[name]
        if not blocks:
            return
        c = {k: np.concatenate([b[k] for b in blocks]) for k in blocks[0] if k != "params"}
        blocks.clear()
        pending_rows[name] = 0
        folds[name].add(c)
        if name == estimator:
            force = np.linalg.norm(c["contact_force_S"], axis=1)
            if contact is None:
                contact = ContactFold(t0, force_limit, period_s or _period(c["t_ns"]))
                skill.period_s = contact.period_s
            contact.add(c["t_ns"], c["contact"].astype(bool), force)
            skill.add_force(c["t_ns"], force, c["contact"].astype(bool))
            series.raw.add(c["t_ns"], np.hstack((c["raw_force"], c["raw_torque"])))
            series.compensated.add(c["t_ns"], np.hstack((c["contact_force_S"], c["contact_torque_S"])))
            series.contact_force.add(c["t_ns"], force)

    def fold_commands() -> None:
        nonlocal command_rows
        if commands and series.command is not None:
            force = np.concatenate([c["force_D"] for c in commands])
            enabled = np.concatenate([c["enabled"] for c in commands])
            series.command.add(
                np.concatenate([c["t_ns"] for c in commands]), np.column_stack((np.linalg.norm(force, axis=1), enabled))
            )
        commands.clear()
        command_rows = 0

    topics = ["/aligned/sample", "/events", *(ESTIMATOR_TOPIC_PREFIX + n for n in names)]
    if plots:
        topics.append("/haptic/command")
    if "/haptic/passivity" in rec.topic_names:
        topics.append("/haptic/passivity")
    topics += [
        t for t in ("/robot/target", "/haptic/state") if t in rec.topic_names and (t != "/haptic/state" or marks >= 0)
    ]
    fast = fast and can_read(rec.path)
    recent: deque[dict[str, np.ndarray]] = deque(maxlen=3 if fast else 32)
    for topic, batch in file_batches(rec.path, topics, fast):
        if topic == "/aligned/sample":
            recent.append(batch)
            aligned_chunk.append(batch)
            aligned_rows += len(batch["t_ns"])
            if aligned_rows >= CHUNK_ROWS:
                fold_aligned()
            if progress is not None and t1 > t0:
                progress(min(1.0, (int(batch["t_ns"][-1]) - t0) / (t1 - t0)))
        elif topic == "/haptic/command":
            commands.append(batch)
            command_rows += len(batch["t_ns"])
            if command_rows >= CHUNK_ROWS:
                fold_commands()
        elif topic == "/haptic/passivity":
            energy, damping = batch["energy_J"], batch["damping"]
            if len(energy):
                port["max_J"] = max(port["max_J"], float(np.nanmax(energy)) if np.isfinite(energy).any() else -math.inf)
                port["damped"] += int(np.count_nonzero(damping > 0))
                port["ticks"] += len(energy)
            if series.passivity is not None:
                series.passivity.add(batch["t_ns"], np.column_stack((energy, damping)))
        elif topic == "/robot/target":
            skill.add_targets(batch)
        elif topic == "/haptic/state":
            skill.add_states(batch)
        elif topic == "/events":
            events.extend(Event(t_ns, m["kind"], m["message"], m.get("data") or {}) for t_ns, m in batch)
        else:
            name = topic[len(ESTIMATOR_TOPIC_PREFIX) :]
            if name == estimator:
                series.params.extend(((t - t0) / 1e9, p) for t, p in batch["params"])
            joined = join_raw(batch, recent)
            if joined is None:
                continue
            pending[name].append(joined)
            pending_rows[name] += len(joined["t_ns"])
            if pending_rows[name] >= CHUNK_ROWS:
                fold_estimator(name)
    fold_aligned()
    for name in names:
        fold_estimator(name)
    fold_commands()
    if progress is not None:
        progress(1.0)

    measured_rate = (
        (health["samples"] - 1) / ((health["last_t"] - health["first_t"]) / 1e9)
        if health["samples"] > 1 and health["last_t"] > health["first_t"]
        else 0.0
    )
    contacts = contact.finish() if contact is not None else []
    summary = rec.metadata.get("hapticlab.summary", {})
    gathered = skill.finish(
        contacts,
        contact.contact_samples * contact.period_s if contact is not None else 0.0,
        contact.over_limit_s if contact is not None else 0.0,
    )
    gathered["peak_force_N"] = contact.peak if contact is not None else None  # (every sample's: as recorded)
    rotation_DB = config.get("haptic", {}).get("rotation_DB", (0.0, 0.0, 0.0))
    task_score, outcome = score(task, gathered, rotation_DB, force_limit)
    return SessionReview(
        path=rec.path,
        name=str(session.get("name", "")),
        trainee=str(session.get("trainee", "")),
        task=str(session.get("task", "")),
        notes=str(session.get("notes", "")),
        date=str(rec.meta("hapticlab.session", "start_time", "") or ""),
        duration_s=duration,
        estimator=estimator,
        sensor_rate_hz=measured_rate,
        samples=health["samples"],
        lost_samples=health["lost"],
        bad_samples=health["bad"],
        kinematics_rate_hz=(counts.get("/kinematics/pose", 0) / duration if duration > 0 else 0.0),
        poses=counts.get("/kinematics/pose", 0),
        estimators=[folds[n].finish() for n in names],
        contacts=contacts,
        force_limit_N=force_limit,
        over_limit_s=contact.over_limit_s if contact is not None else 0.0,
        contact_s=(contact.contact_samples * contact.period_s) if contact is not None else 0.0,
        peak_force_N=contact.peak if contact is not None else float("nan"),
        haptic_on_s=sum(off - on for on, off, _ in haptic_on_runs(events, t1)) / 1e9,
        port_energy_max_J=port["max_J"] if port["ticks"] and port["max_J"] > -math.inf else None,
        damping_share=port["damped"] / port["ticks"] if port["ticks"] else None,
        events=events,
        complete=bool(summary),
        start_ns=t0,
        series=series if plots else None,
        skill={**{k: gathered.get(k) for k in KEYS}, "task_score": task_score},
        outcome=outcome,
        task_settings=task,
        excess_events=gathered["events"],
    )


def _period(t_ns: np.ndarray) -> float:
    """A sample period from the samples' stamps, s (median step; 1 ms when there is one sample)."""
    return float(np.median(np.diff(t_ns))) / 1e9 if len(t_ns) > 1 else 1e-3
