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

from ...core.plugins import ConfigError, Registry
from ...core.types import Estimates, first_true

from ..config import parse_value
from ..recording.csvimport import CsvError, write_compensated_csv
from ..recording.stream import Stream, load_stream
from .metrics import rms_after_convergence

BLOCK = 1024
"""Samples per estimator call offline (the result does not depend on it)."""


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
    recording: str | Path | Stream,
    out_csv: str | Path,
    estimator_name: str = "rls",
    overrides: list[str] | None = None,
    params_out: str | Path | None = None,
    registry: Registry | None = None,
    progress=None,
) -> CompensateResult:
    """Run ``estimator_name`` over a recording (a stream, or a CSV or MCAP file) and write the contact wrench per row."""
    registry = registry if registry is not None else Registry()
    options = estimator_options(overrides or [])
    estimator_name = options.pop("name", estimator_name)
    out_csv = Path(out_csv)
    source = recording.source if isinstance(recording, Stream) else str(recording)
    if source and out_csv.resolve() == Path(source).resolve():
        raise CsvError(f"{out_csv}: the output would overwrite the input; choose another -o")
    for target in (out_csv, Path(params_out) if params_out else None):
        if target is not None and not target.parent.is_dir():
            raise CsvError(f"{target}: folder {target.parent} does not exist")
    estimator = registry.create("estimator", estimator_name, options, where="estimator")
    stream = recording if isinstance(recording, Stream) else load_stream(recording)
    est = run_estimator(stream, estimator, progress)
    write_compensated_csv(out_csv, stream.t_s, est.contact_force_S, est.contact_torque_S,
                          est.contact, est.converged_force, est.converged_torque)
    first_f, first_t = first_true(est.converged_force), first_true(est.converged_torque)
    rms_f = rms_after_convergence(est.contact_force_S, est.contact, first_f)
    rms_t = rms_after_convergence(est.contact_torque_S, est.contact, first_t)
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
