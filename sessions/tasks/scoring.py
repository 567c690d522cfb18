"""A task's outcome and score (0–100 %) from what the review gathered (``review/skill_fold.py``).

* **palpation**: the mark's distance to the inclusion, across the surface: the flange's move from where
  the trainee took control to where the mark was pressed, against ``inclusion_offset_B`` (the tool's
  orientation is held while following, so the tip moves as the flange). Full marks within one radius,
  none beyond two, linear between; times ``force_limit / peak force`` when the peak went over the limit
  (the force used). No mark, no score (0 %).
* **retraction**: the time the contact force spent inside ``band`` over the ``hold`` asked, capped at 100 %.
* **tracing**: the line runs ``span`` along the master's x (as the mapping turns it into B) centred on
  where the trainee took control. The RMS distance across the surface of the flange's path from the line,
  while in contact, scales the score linearly to 0 at ``tolerance``; times the share of the line's length
  covered; minus 10 points per excessive-force event.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hapticlab.core.frames import matrix_from_rotvec

EVENT_PENALTY = 10.0
"""Points a tracing loses per excessive-force event."""


def score(
    task: dict[str, Any], gathered: dict[str, Any], rotation_DB=(0.0, 0.0, 0.0), force_limit: float | None = None
) -> tuple[float | None, dict]:
    """(score %, the outcome's details) of the recorded ``task`` table; (None, {}) without a task.
    ``force_limit``: the limit the review counted events above, N (the task's when None): the score uses it."""
    if force_limit is not None:
        task = {**task, "force_limit": force_limit}
    name = task.get("name", "")
    normal = np.asarray(task.get("normal_B", (0.0, 0.0, 1.0)), dtype=float)
    normal = normal / np.linalg.norm(normal)
    if name == "palpation":
        return _palpation(task, gathered, normal)
    if name == "retraction":
        done = gathered["in_band_s"] / float(task["hold"])
        return round(100.0 * min(1.0, done), 1), {"time_in_band_s": gathered["in_band_s"]}
    if name == "tracing":
        x_B = matrix_from_rotvec(np.asarray(rotation_DB, dtype=float)).T[:, 0]
        return _tracing(task, gathered, normal, x_B)
    return None, {}


def _across(v: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """``v`` (…, 3) with its component along the surface's normal removed."""
    return v - np.multiply.outer(v @ normal, normal)


def _palpation(task: dict[str, Any], gathered: dict[str, Any], normal: np.ndarray) -> tuple[float | None, dict]:
    offset = np.asarray(task.get("inclusion_offset_B") or (), dtype=float)
    if offset.shape != (3,):
        return None, {"mark_error_m": None, "marks": len(gathered["marks"])}  # no truth to score against
    if not gathered["marks"] or gathered["first_p"] is None:
        return 0.0, {"mark_error_m": None, "marks": 0}
    t_mark, p_mark = gathered["marks"][0]
    error = float(np.linalg.norm(_across(p_mark - gathered["first_p"] - offset, normal)))
    radius = float(task["inclusion_radius"])
    closeness = min(1.0, max(0.0, 2.0 - error / radius))
    peak = gathered.get("peak_force_N") or 0.0
    force = min(1.0, float(task["force_limit"]) / peak) if peak > 0 else 1.0
    return round(100.0 * closeness * force, 1), {
        "mark_error_m": error,
        "mark_s": t_mark,
        "marks": len(gathered["marks"]),
    }


def _tracing(task: dict[str, Any], gathered: dict[str, Any], normal: np.ndarray, x_B: np.ndarray):
    t, p = gathered["targets"]  # (k,) s and (k, 3) m: the flange's targets, every 10 ms
    if gathered["first_p"] is None or not len(t):
        return 0.0, {"path_error_m": None, "coverage": 0.0}
    touching = np.zeros(len(t), bool)
    for start, end in gathered["contacts"]:
        touching |= (t >= start) & (t <= end)
    if not touching.any():
        return 0.0, {"path_error_m": None, "coverage": 0.0}
    d = _across(p[touching] - gathered["first_p"], normal)
    e = _across(x_B, normal)
    e = e / np.linalg.norm(e)
    half = 0.5 * float(task["span"])
    along = np.clip(d @ e, -half, half)
    error = float(np.sqrt(np.mean(np.sum((d - np.outer(along, e)) ** 2, axis=1))))
    coverage = float((along.max() - along.min()) / (2 * half)) if half > 0 else 1.0
    closeness = max(0.0, 1.0 - error / float(task["tolerance"]))
    points = 100.0 * closeness * coverage - EVENT_PENALTY * gathered["excess_force_events"]
    details = {"path_error_m": error, "coverage": coverage}
    return round(max(0.0, points), 1), details if math.isfinite(error) else {"path_error_m": None, "coverage": 0.0}
