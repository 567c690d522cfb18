"""Sampling a simulated world and running an estimator over the samples as a session would (in order, in blocks)."""

from __future__ import annotations

from typing import Any

import numpy as np

from hapticlab.core.types import AlignedSamples, Estimates
from hapticlab.plugins.simworld import SimWorld


def simulate(world: SimWorld, seconds: float, rate_hz: float, t0: float = 0.0) -> tuple[AlignedSamples, dict]:
    """Sample the world's sensor and orientation for ``seconds`` from ``t0``."""
    t = t0 + np.arange(round(seconds * rate_hz)) / rate_hz
    w = world.wrench(t)
    n = len(t)
    block = AlignedSamples(
        t_ns=np.round(t * 1e9).astype(np.int64),
        force_S=np.array(w["force_S"]),
        torque_S=np.array(w["torque_S"]),
        R_EB=w["R_EB"],
        seq=np.arange(n),
        status=np.asarray(w["status"]),
        stale=np.zeros(n, dtype=bool),
    )
    return block, w


def feed(estimator: Any, block: AlignedSamples, chunk: int = 1024, trace_until: int = 0) -> tuple[Estimates, Any]:
    """Run a block through the estimator; trace its parameters sample by sample for ``trace_until`` samples.

    Returns (estimates, (trace sample indices, {name: (k, 3)})) or (estimates, None).
    """
    parts: list[Estimates] = []
    index: list[int] = []
    trace: dict[str, list] = {}
    i = 0
    n = len(block)
    while i < n:
        step = 1 if i < trace_until else chunk
        part = estimator.update_block(block.subset(slice(i, i + step)))
        parts.append(part)
        i += len(part)
        if trace_until:
            index.append(i - 1)
            for key, value in estimator.params().items():
                trace.setdefault(key, []).append(value)
    est = Estimates.concatenate(parts, params=estimator.params())
    traced = (np.array(index), {k: np.array(v) for k, v in trace.items()}) if trace_until else None
    return est, traced
