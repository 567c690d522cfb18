"""The review's pass over a recording: the topics it needs in file order, as columns, estimators joined to raw.

:func:`file_batches` reads a finished format-3 file a few chunks at a time as
columns (``recording.columnar``), any other a message at a time
(``recording.messages.iter_blocks``): the same batches either way.
:func:`join_raw` gives each estimator sample the raw aligned reading it was
estimated from, so the paper's "before" and "after" are the same sample's.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.sessions.recording.columnar import NUMBER, TEXT, iter_chunks, picked
from hapticlab.sessions.recording.messages import iter_blocks

COMMAND_FIELDS = {"force_D": 3, "enabled": 0}
"""What a review reads of each ``/haptic/command`` (as columns: ``recording.columnar``)."""
PASSIVITY_FIELDS = {"energy_J": NUMBER, "damping": NUMBER}
"""...and of each ``/haptic/passivity`` (teleoperation: the port's energy, J, and the damping added, N·s/m)."""
TARGET_FIELDS = {"p_BoEo_B": 3, "mode": TEXT, "reason": TEXT}
"""...of each ``/robot/target`` (teleoperation: the flange's target, m in B, and why it follows or holds)."""
STATE_FIELDS = {"buttons": NUMBER}
"""...and of each ``/haptic/state`` (the master's buttons: a task's marks)."""
COLUMNS = {
    "/haptic/command": COMMAND_FIELDS,
    "/haptic/passivity": PASSIVITY_FIELDS,
    "/robot/target": TARGET_FIELDS,
    "/haptic/state": STATE_FIELDS,
}


def file_batches(path: Path, topics: list[str], fast: bool) -> Iterator[tuple[str, Any]]:
    """``(topic, batch)`` in file order: a block topic's samples as columns (with ``params``:
    ``[(t_ns, params)]``), any other topic's ``[(t_ns, message)]``; a chunk's aligned samples first."""
    if fast:
        for chunk in iter_chunks(path, topics, json_fields={t: COLUMNS[t] for t in topics if t in COLUMNS}):
            for topic in sorted(chunk, key=lambda t: t != "/aligned/sample"):
                if len(chunk[topic]):
                    yield topic, chunk[topic]
        return
    for topic, t_ns, m, is_block in iter_blocks(path, topics):
        if topic in COLUMNS:  # the same columns as the fast path's, from the one message
            yield topic, picked([m], np.array([t_ns]), COLUMNS[topic])
            continue
        if not is_block:
            yield topic, [(t_ns, m)]
            continue
        params = m.pop("params", None)
        m.pop("cov_diag", None)
        params = json.loads(params) if isinstance(params, str) else params
        m["params"] = [] if params is None else [(int(m["t_ns"][-1]), params)]
        yield topic, m


def join_raw(block: dict[str, np.ndarray], recent: deque) -> dict[str, np.ndarray] | None:
    """An estimator block with the raw aligned reading of each of its samples (found by stamp in ``recent``).

    The loop writes a tick's aligned block before its estimators' blocks, and an estimator's samples are
    some of those aligned samples; samples not found (a damaged file) are dropped.
    """
    if not recent:
        return None
    last = recent[-1]
    if len(last["t_ns"]) == len(block["t_ns"]) and np.array_equal(last["t_ns"], block["t_ns"]):  # the usual case
        out = dict(block)
        out["raw_force"], out["raw_torque"] = last["force_S"], last["torque_S"]
        return out
    t = np.concatenate([b["t_ns"] for b in recent])
    i = np.searchsorted(t, block["t_ns"])
    i = np.clip(i, 0, len(t) - 1)
    found = t[i] == block["t_ns"]
    if not found.any():
        return None
    force = np.concatenate([b["force_S"] for b in recent])
    torque = np.concatenate([b["torque_S"] for b in recent])
    out = {k: (v[found] if isinstance(v, np.ndarray) and len(v) == len(found) else v) for k, v in block.items()}
    out["raw_force"], out["raw_torque"] = force[i[found]], torque[i[found]]
    return out
