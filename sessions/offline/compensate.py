"""Offline compensation: run an estimator over a CSV file or an MCAP recording.

The estimator sees the rows in order, in blocks, exactly as it would live; the
output has one row per input row (the estimated contact wrench in S and the
contact and convergence flags).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...core.aligner import orientation_at, position_at
from ...core.frames import matrix_from_quat_wxyz
from ...core.plugins import ConfigError, Registry
from ...core.types import AlignedSamples, Estimates, first_true

from ..config import parse_value
from ..recording.csvimport import CsvError, read_csv, write_compensated_csv

BLOCK = 1024
"""Samples per estimator call offline (the result does not depend on it)."""


@dataclass
class Stream:
    """The input of an offline run: every row as an aligned sample, with its time in s."""

    t_s: np.ndarray
    samples: AlignedSamples
    notes: list[str]

    def __len__(self) -> int:
        return len(self.t_s)


def load_stream(path: str | Path) -> Stream:
    """Read a CSV (import contract) or an MCAP recording into an aligned stream."""
    path = Path(path)
    if not path.exists():
        raise CsvError(f"{path}: no such file")
    if path.suffix.lower() == ".mcap":
        return _load_mcap(path)
    record = read_csv(path)
    n = len(record)
    t_ns = np.round((record.t_s - record.t_s[0]) * 1e9).astype(np.int64)
    samples = AlignedSamples(t_ns, record.force_S, record.torque_S, record.R_EB, np.arange(n),
                             np.zeros(n, dtype=np.int64), np.zeros(n, dtype=bool), record.quat_BE,
                             record.p_BoEo_B)
    return Stream(record.t_s, samples, record.notes)


def _load_mcap(path: Path) -> Stream:
    from ..recording import read_recording

    recording = read_recording(path)
    wrenches = recording.topics.get("/sensor/wrench", [])
    poses = recording.topics.get("/kinematics/pose", [])
    if not wrenches:
        raise CsvError(f"{path.name}: no /sensor/wrench messages")
    if not poses:
        raise CsvError(f"{path.name}: no /kinematics/pose messages")
    t_ns = np.array([t for t, _ in wrenches], dtype=np.int64)
    # NaN is recorded as null in JSON; float(None) would fail, so map it back
    force_S = np.array([[np.nan if v is None else v for v in m["force_S"]] for _, m in wrenches], dtype=float)
    torque_S = np.array([[np.nan if v is None else v for v in m["torque_S"]] for _, m in wrenches], dtype=float)
    status = np.array([int(m.get("status", 0)) for _, m in wrenches], dtype=np.int64)
    pose_t = np.array([t for t, _ in poses], dtype=np.int64)
    quat = np.array([m["quat_BE"] for _, m in poses], dtype=float)
    period = int(np.median(np.diff(pose_t))) if len(pose_t) > 1 else 0
    quat_BE, stale = orientation_at(t_ns, pose_t, quat, period)
    R_EB = matrix_from_quat_wxyz(quat_BE).transpose(0, 2, 1)
    p_BoEo_B = None
    if all(m.get("p_BoEo_B") is not None for _, m in poses):
        p_BoEo_B = position_at(t_ns, pose_t, np.array([m["p_BoEo_B"] for _, m in poses], dtype=float), period)
    seq = np.array([int(m.get("seq", k)) for k, (_, m) in enumerate(wrenches)], dtype=np.int64)
    samples = AlignedSamples(t_ns, force_S, torque_S, R_EB, seq, status, stale, quat_BE, p_BoEo_B)
    unused = int(np.count_nonzero(~samples.usable))
    notes = [f"{path.name}: {unused} sample(s) not used (stale orientation, sensor status or non-finite)"] \
        if unused else []
    return Stream((t_ns - t_ns[0]) * 1e-9, samples, notes)


def estimator_options(overrides: list[str]) -> dict[str, Any]:
    """Estimator options from ``--set estimator.key=value`` (or ``key=value``).

    ``estimator.name=...`` is returned under ``name`` (it picks the estimator).
    """
    options: dict[str, Any] = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected key=value, e.g. estimator.force_threshold=2")
        if key.startswith("estimator."):
            key = key[len("estimator."):]
        elif "." in key:
            raise ConfigError(f"{key}: compensate takes estimator options only (estimator.<option>=value)")
        options[key] = parse_value(value)
    return options


def run_estimator(stream: Stream, estimator: Any, progress=None) -> Estimates:
    """Feed the usable rows through the estimator in blocks; one estimate row per input row.

    Rows the estimator may not see get NaN wrench values, no contact, and the
    convergence flags of the row before them.
    """
    n = len(stream)
    ok = stream.samples.usable
    usable = np.flatnonzero(ok)
    force = np.full((n, 3), np.nan)
    torque = np.full((n, 3), np.nan)
    contact = np.zeros(n, dtype=bool)
    conv_f = np.zeros(n, dtype=bool)
    conv_t = np.zeros(n, dtype=bool)
    for i in range(0, len(usable), BLOCK):
        rows = usable[i : i + BLOCK]
        est = estimator.update_block(stream.samples.subset(rows))
        force[rows], torque[rows], contact[rows] = est.contact_force_S, est.contact_torque_S, est.contact
        conv_f[rows], conv_t[rows] = est.converged_force, est.converged_torque
        if progress is not None:
            progress(int(rows[-1]) + 1, n)
    if len(usable) < n:  # carry the flags over the rows the estimator did not see
        last = np.maximum.accumulate(np.where(ok, np.arange(n), -1))
        seen = last >= 0
        conv_f[seen], conv_t[seen] = conv_f[last[seen]], conv_t[last[seen]]
    return Estimates(stream.samples.t_ns, force, torque, contact, conv_f, conv_t,
                     params=estimator.params(), cov_diag=estimator.cov_diag())


def _rms_after(values: np.ndarray, contact: np.ndarray, first: int | None) -> np.ndarray:
    """Per-axis RMS over no-contact rows from the first convergence on (NaN if none)."""
    if first is None:
        return np.full(3, np.nan)
    rows = ~contact[first:] & np.isfinite(values[first:]).all(1)
    return np.sqrt(np.mean(values[first:][rows] ** 2, axis=0)) if rows.any() else np.full(3, np.nan)


@dataclass
class CompensateResult:
    """What ``compensate`` did, for the summary it prints."""

    rows: int
    estimates: Estimates
    params: dict[str, Any]
    rms_force_S: list[float]
    """per-axis RMS of the contact force over no-contact rows after the first convergence, N"""
    rms_torque_S: list[float]
    first_converged_force: int | None
    first_converged_torque: int | None
    notes: list[str]


def compensate(
    input_path: str | Path,
    out_csv: str | Path,
    estimator_name: str = "rls",
    overrides: list[str] | None = None,
    params_out: str | Path | None = None,
    registry: Registry | None = None,
    progress=None,
) -> CompensateResult:
    """Run ``estimator_name`` over a recording and write the contact wrench per row."""
    registry = registry if registry is not None else Registry()
    options = estimator_options(overrides or [])
    estimator_name = options.pop("name", estimator_name)
    input_path, out_csv = Path(input_path), Path(out_csv)
    if out_csv.resolve() == input_path.resolve():
        raise CsvError(f"{out_csv}: the output would overwrite the input; choose another -o")
    for target in (out_csv, Path(params_out) if params_out else None):
        if target is not None and not target.parent.is_dir():
            raise CsvError(f"{target}: folder {target.parent} does not exist")
    estimator = registry.create("estimator", estimator_name, options, where="estimator")
    stream = load_stream(input_path)
    est = run_estimator(stream, estimator, progress)
    write_compensated_csv(out_csv, stream.t_s, est.contact_force_S, est.contact_torque_S,
                          est.contact, est.converged_force, est.converged_torque)
    first_f, first_t = first_true(est.converged_force), first_true(est.converged_torque)
    rms_f = _rms_after(est.contact_force_S, est.contact, first_f)
    rms_t = _rms_after(est.contact_torque_S, est.contact, first_t)
    params: dict[str, Any] = dict(estimator.params())
    params.update({
        "estimator": estimator_name,
        "samples": len(stream),
        "first_converged_force": first_f,
        "first_converged_torque": first_t,
        "cov_diag": est.cov_diag,
    })
    if params_out:
        Path(params_out).write_text(json.dumps(params, indent=2) + "\n", encoding="utf-8")
    return CompensateResult(len(stream), est, params, rms_f.tolist(), rms_t.tolist(), first_f,
                            first_t, stream.notes)
