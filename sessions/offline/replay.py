"""``hapticlab replay``: re-run a recording through another estimator and compare.

The recorded sensor and pose streams are aligned offline (every sample
interpolated between poses) and fed to the named estimator exactly as a session
would; the new MCAP holds everything the original did plus the new estimator's
topic, and a table compares every estimator in it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import UserError
from ...core.plugins import Registry
from ...core.types import first_true

from ..recording import Recorder, read_recording
from ..recording.stream import load_stream
from .compensate import estimator_options, run_estimator
from .metrics import max_ae, rms, scored_rows


def replay(recording_path: str | Path, estimator_name: str, out_path: str | Path | None = None,
           overrides: list[str] | None = None, registry: Registry | None = None) -> dict[str, Any]:
    """Replay a recording through ``estimator_name``; returns the comparison (and writes ``out_path``)."""
    registry = registry if registry is not None else Registry()
    recording_path = Path(recording_path)
    options = estimator_options(overrides or [])
    estimator_name = options.pop("name", estimator_name)
    estimator = registry.create("estimator", estimator_name, options, where="estimator")
    original = read_recording(recording_path)
    stream = load_stream(recording_path)
    est = run_estimator(stream, estimator)

    label = estimator_name
    while f"/estimator/{label}" in original.topics:
        label += "_replay"
    topic = f"/estimator/{label}"
    flags = {
        "contact_force_S": est.contact_force_S.tolist(), "contact_torque_S": est.contact_torque_S.tolist(),
        "contact": est.contact.tolist(), "converged_force": est.converged_force.tolist(),
        "converged_torque": est.converged_torque.tolist(),
    }
    if out_path is not None:
        out_path = Path(out_path)
        if out_path.resolve() == recording_path.resolve():
            raise UserError(f"{out_path}: the replay would overwrite the recording; choose another -o")
        metadata = {name: dict(values) for name, values in original.metadata.items()}
        metadata["hapticlab.replay"] = {"source": str(recording_path), "estimator": estimator_name,
                                        "topic": topic, "options": json.dumps(options)}
        with Recorder(out_path, metadata=metadata) as rec:
            # every original message in time order, then the new estimator's
            for name, messages in original.topics.items():
                for t_ns, message in messages:
                    rec.write(name, t_ns, message)
            n = len(est)
            for i, t_ns in enumerate(stream.samples.t_ns.tolist()):
                rec.write(topic, t_ns, {key: values[i] for key, values in flags.items()} | {
                    "params": estimator.params() if i == n - 1 else None,
                    "cov_diag": estimator.cov_diag() if i == n - 1 else None,
                })
    return {"topic": topic, "estimator": estimator_name, "rows": len(est),
            "comparison": compare(original, stream.samples.t_ns, {topic: est}),
            "params": estimator.params()}


def _recorded(original, topic: str, t_ns: np.ndarray) -> dict[str, np.ndarray] | None:
    """A recorded estimator topic as arrays aligned to the wrench sample times."""
    messages = original.topics.get(topic, [])
    if not messages:
        return None
    index = {t: k for k, (t, _) in enumerate(messages)}
    rows = [index.get(int(t)) for t in t_ns]
    nan3 = [float("nan")] * 3
    pick = lambda key, empty: np.array(  # noqa: E731
        [messages[k][1][key] if k is not None else empty for k in rows], dtype=float)
    return {
        "contact_force_S": pick("contact_force_S", nan3),  # null (a recorded NaN) becomes NaN
        "contact": pick("contact", 0.0).astype(bool),
        "converged_force": pick("converged_force", 0.0).astype(bool),
        "seen": np.array([k is not None for k in rows]),
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
        series[topic] = {"contact_force_S": est.contact_force_S, "contact": est.contact,
                         "converged_force": est.converged_force, "seen": np.isfinite(est.contact_force_S).all(1)}
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
