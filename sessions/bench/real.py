"""``hapticlab bench real``: every registered estimator on real recordings.

For each CSV file of a folder and each registered estimator with its defaults
(``kalman``, the default, first; ``kalman`` once more with the identified
convergence rule, whose flag waits for the motion to identify the tool where the
default's is up once the wrench is known at the pose; and once more with the
simulated Gamma sensor's noise and the covariance convergence rule, its defaults
before it estimated the noise; and once more without the bias's walk over the tool's tilt,
``bias_force_tilt_rw = 0``, its former default; and once more with its torque stage started once the force
stage has settled, ``torque_start = "settled"``, its former default):
the online RMS of the estimated contact force per axis over every row after the first convergence, against the
offline batch fit of the whole file evaluated over the same rows (their ratio); the same ratio over
the file's second half, a window that does not depend on each estimator's own
convergence test; ``kalman`` once more with the effects ``hapticlab discrepancy``
names on the same file (their values fitted offline on that file, so this row
is in-sample for them); the share of rows the estimator judged a contact, and the
samples each stage took to converge by its own criterion. The recordings are
contact-free calibration logs, so every row judged a contact is a false contact, and
those rows are scored like the rest. An estimator that holds lone outliers out of its
update without calling them contacts (``HoldsOutOutliers``) has those counted beside.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.errors import UserError
from hapticlab.core.estimation.batch import batch_fit
from hapticlab.core.host.interfaces import HoldsOutOutliers
from hapticlab.core.host.registry import Registry
from hapticlab.core.types import first_true
from hapticlab.sessions.offline.compensate import run_estimator
from hapticlab.sessions.offline.metrics import norm_ratio, rms, scored_rows
from hapticlab.sessions.offline.numerics import numerical_failures
from hapticlab.sessions.recording.loader import load_stream
from hapticlab.sessions.recording.stream import Stream


def default_real_dir() -> Path:
    """``$HAPTICLAB_REAL_DATA``, else ``shared/data/real`` beside the source checkout, else ``../shared/data/real``."""
    env = os.environ.get("HAPTICLAB_REAL_DATA")
    if env:
        return Path(env)
    beside_checkout = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
    return beside_checkout if beside_checkout.is_dir() else Path("../shared/data/real")


REAL_COLUMNS = (
    "file",
    "estimator",
    "force conv.",
    "torque conv.",
    "contact",
    "held out",
    "RMS fx, fy, fz (N)",
    "batch, same rows",
    "ratio per axis",
    "ratio ‖·‖",
    "2nd half",
    "last 70 %: force",
    "torque",
)
"""The columns of bench real's table, on the terminal and in docs/results.md (``table_rows``)."""
LAST_SHARE = 0.7
"""The window every estimator is scored over beside its own convergence: the file's last 70 % of rows, wherever
each flag rose (a torque stage that starts late shows here, its raw torque standing in until then)."""
IDENTIFIED = {"convergence": "identified"}
"""kalman's convergence rule before "pose": the wrench known at the pose and the tool identified by the motion."""
GAMMA_COVARIANCE = {"noise_force": 0.12, "noise_torque": 0.01, "convergence": "covariance"}
"""kalman's options before it estimated the noise: the simulated Gamma-class sensor's noise, convergence from P."""
SETTLED_TORQUE = {"torque_start": "settled"}
"""kalman's torque stage started once the force stage has settled (its default before), not from the first sample."""
NO_TILT_WALK = {"bias_force_tilt_rw": 0.0}
"""kalman without the bias's walk over the tool's tilt (learnt by default: docs/estimators.md, "The tilt walk")."""


def variants(registry: Registry, stream: Stream) -> list[tuple[str, str, dict[str, Any] | str]]:
    """(label, estimator name, options or an error): every registered estimator with its defaults, the
    default (kalman) first; kalman with the identified rule, with the Gamma figures and the covariance rule
    (its defaults before), without the bias's tilt walk (its default before), with its torque stage started
    once the force stage has settled (its default before); and
    kalman with the effects ``hapticlab discrepancy`` names on the file."""
    names = registry.names("estimator")
    names = sorted(names, key=lambda name: name != "kalman")  # the default first, then the others as registered
    out: list[tuple[str, str, dict[str, Any] | str]] = [(name, name, {}) for name in names]
    if "kalman" in names:
        out.append(("kalman convergence=identified", "kalman", dict(IDENTIFIED)))
        out.append(("kalman noise=0.12 N, convergence=covariance", "kalman", dict(GAMMA_COVARIANCE)))
        out.append(("kalman bias_force_tilt_rw=0", "kalman", dict(NO_TILT_WALK)))
        out.append(("kalman torque_start=settled", "kalman", dict(SETTLED_TORQUE)))
        from hapticlab.sessions.discrepancy.workflow import discrepancy

        try:
            named = discrepancy(stream, registry=registry)["estimator_options"]
        except UserError as exc:  # too short a file, its numbers defeat a solver: said in the row
            named = f"discrepancy: {exc}"
        out.append(("kalman + named effects", "kalman", named))
    return out


def last_rows_ratio(online: np.ndarray, residual: np.ndarray) -> list[float]:
    """Per axis, the online RMS over the batch fit's over the last ``LAST_SHARE`` of the rows (finite online
    ones): force (N) or torque (N·m), whatever each estimator's flag says; NaN with no such row."""
    rows = scored_rows(len(online) - round(LAST_SHARE * len(online)), online)
    return (rms(online[rows]) / rms(residual[rows])).tolist()


def second_half_ratio(contact_force_S: np.ndarray, residual_force_S: np.ndarray) -> float:
    """‖online RMS‖ / ‖batch-fit RMS‖ of the force over the rows of the second half (finite online ones)."""
    rows = scored_rows(len(contact_force_S) // 2, contact_force_S)
    return norm_ratio(rms(contact_force_S[rows]), rms(residual_force_S[rows]))


def bench_real(
    folder: Path, registry: Registry | None = None, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Results per file, then per estimator (JSON-ready)."""
    registry = registry if registry is not None else Registry()
    folder = Path(folder)
    if not folder.is_dir():
        raise UserError(f"{folder}: no such folder; give one: hapticlab bench real DIR")
    files = sorted(folder.glob("*.csv"))
    if not files:
        raise UserError(f"{folder}: no CSV files to evaluate")
    out: dict[str, Any] = {}
    for path in files:
        try:  # one bad file does not stop the others: its error goes in its row
            with numerical_failures(path.name):
                out[path.stem] = bench_file(path, registry, progress)
        except UserError as exc:
            out[path.stem] = {"error": str(exc)}
    return out


def bench_file(path: Path, registry: Registry, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One file's entry: the batch fit, then every estimator variant (an estimator that fails on the file,
    or whose options cannot be had, gets its error in its row)."""
    stream = load_stream(path)
    s = stream.samples
    fit = batch_fit(s.force_S, s.torque_S, s.R_EB)
    residual = fit["residual_force_S"]
    entry: dict[str, Any] = {"rows": len(stream), "batch_rms_force_S": rms(residual).tolist(), "estimators": {}}
    for label, name, options in variants(registry, stream):
        if progress:
            progress(f"{path.name}: {label}")
        if isinstance(options, str):  # the options could not be had: say why in the row
            entry["estimators"][label] = {"error": options}
            continue
        if label.endswith("named effects"):
            entry["named_effects"] = options.get("effects", [])
        try:
            estimator = registry.create("estimator", name, options, where="estimator")
            est = run_estimator(stream, estimator)
        except UserError as exc:
            entry["estimators"][label] = {"error": str(exc)}
            continue
        first_f, first_t = first_true(est.converged_force), first_true(est.converged_torque)
        result: dict[str, Any] = {
            "converged_force_at": first_f,
            "converged_torque_at": first_t,
            "contact_rows": int(est.contact.sum()),
            "contact_pct": 100.0 * float(np.mean(est.contact)),
        }
        if isinstance(estimator, HoldsOutOutliers):  # refused, not called contacts: shown beside
            result["held_out_rows"] = estimator.held_out_samples
            result["held_out_pct"] = 100.0 * estimator.held_out_samples / max(len(stream), 1)
        result["ratio_norm_second_half"] = second_half_ratio(est.contact_force_S, residual)
        result["last_ratio_force"] = last_rows_ratio(est.contact_force_S, residual)
        result["last_ratio_torque"] = last_rows_ratio(est.contact_torque_S, fit["residual_torque_S"])
        if first_f is not None:  # contact rows are scored too: every one is a false contact
            rows = scored_rows(first_f, est.contact_force_S)
            online, batch = rms(est.contact_force_S[rows]), rms(residual[rows])
            result.update(
                {
                    "rows_scored": int(rows.sum()),
                    "rms_force_S": online.tolist(),
                    "batch_rms_same_rows": batch.tolist(),
                    "ratio": (online / batch).tolist(),
                    "ratio_norm": norm_ratio(online, batch),
                }
            )
        entry["estimators"][label] = result
    return entry


def table_rows(
    out: dict[str, Any],
    fmt: Callable[[Any, int], str],
    vec: Callable[[Any, int], str],
    name: Callable[[str], str] = str,
) -> list[tuple[tuple[str, ...], bool]]:
    """The rows of ``bench_real``'s numbers under :data:`REAL_COLUMNS`, each with whether it ends a file's;
    numbers written with ``fmt(value, digits)``, vectors with ``vec(values, digits)``, names with ``name``.
    The last two columns are the worst axis of ``last_ratio_force`` and ``last_ratio_torque``."""

    def worst(values: list[float | None] | None) -> str:  # (a NaN saved to JSON comes back None)
        finite = [v for v in values or [] if v is not None and math.isfinite(v)]
        return fmt(max(finite), 2) if finite else "–"

    rows: list[tuple[tuple[str, ...], bool]] = []
    blank = ("",) * (len(REAL_COLUMNS) - 7)
    for file, entry in out.items():
        if "error" in entry:
            rows.append(((name(file), "", "", "", "", "", entry["error"], *blank), True))
            continue
        for k, (label, r) in enumerate(entry["estimators"].items()):
            first = f"{name(file)} ({entry['rows']} rows)" if k == 0 else ""
            last = k == len(entry["estimators"]) - 1
            if label.endswith("named effects"):
                label += " (" + (", ".join(entry.get("named_effects", [])) or "none") + ")"
            if "error" in r:
                rows.append(((first, name(label), "", "", "", "", r["error"], *blank), last))
                continue
            held = f"{r['held_out_pct']:.1f} % ({r['held_out_rows']})" if "held_out_pct" in r else "–"
            row = (
                first,
                name(label),
                fmt(r["converged_force_at"], 0),
                fmt(r["converged_torque_at"], 0),
                f"{r['contact_pct']:.1f} % ({r['contact_rows']})",
                held,
                vec(r["rms_force_S"], 3) if r.get("rms_force_S") else "never converged",
                vec(r.get("batch_rms_same_rows"), 3),
                vec(r.get("ratio"), 2),
                fmt(r.get("ratio_norm"), 2),
                fmt(r.get("ratio_norm_second_half"), 2),
                worst(r.get("last_ratio_force")),
                worst(r.get("last_ratio_torque")),
            )
            rows.append((row, last))
    return rows
