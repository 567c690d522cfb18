"""``hapticlab bench real``: every registered estimator on real recordings.

For each CSV file of a folder (default ``../shared/data/real``) and each
registered estimator: the online RMS of the contact force per axis over the
no-contact rows after the first convergence, against the offline batch fit of
the whole file evaluated over the same rows (their ratio), and the samples
each stage took to converge by the estimator's own criterion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np

from hapticlab.core.batch import batch_fit
from hapticlab.core.plugins import Registry

from .compensate import load_stream, run_estimator

DEFAULT_REAL_DIR = Path("../shared/data/real")


def bench_real(folder: Path, registry: Registry | None = None,
               progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Results per file, then per estimator (JSON-ready)."""
    registry = registry if registry is not None else Registry()
    files = sorted(Path(folder).glob("*.csv"))
    if not files:
        raise FileNotFoundError(f"{folder}: no CSV files to evaluate")
    out: dict[str, Any] = {}
    for path in files:
        stream = load_stream(path)
        s = stream.samples
        fit = batch_fit(s.force_S, s.torque_S, s.R_EB)
        residual = fit["residual_force_S"]
        entry: dict[str, Any] = {
            "rows": len(stream),
            "batch_rms_force_S": np.sqrt(np.mean(residual ** 2, axis=0)).tolist(),
            "estimators": {},
        }
        for name in registry.names("estimator"):
            if progress:
                progress(f"{path.name}: {name}")
            est = run_estimator(stream, registry.create("estimator", name, {}, where="estimator"))
            first_f = int(np.argmax(est.converged_force)) if est.converged_force.any() else None
            first_t = int(np.argmax(est.converged_torque)) if est.converged_torque.any() else None
            result: dict[str, Any] = {"converged_force_at": first_f, "converged_torque_at": first_t,
                                      "contact_rows": int(est.contact.sum())}
            if first_f is not None:
                rows = np.arange(len(stream)) >= first_f
                rows &= ~est.contact & np.isfinite(est.contact_force_S).all(1)
                online = np.sqrt(np.mean(est.contact_force_S[rows] ** 2, axis=0))
                batch = np.sqrt(np.mean(residual[rows] ** 2, axis=0))
                result.update({
                    "rows_scored": int(rows.sum()),
                    "rms_force_S": online.tolist(),
                    "batch_rms_same_rows": batch.tolist(),
                    "ratio": (online / batch).tolist(),
                    "ratio_norm": float(np.linalg.norm(online) / np.linalg.norm(batch)),
                })
            entry["estimators"][name] = result
        out[path.stem] = entry
    return out
