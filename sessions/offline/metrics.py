"""The compensation metrics, each computed here and nowhere else (``DESIGN.md``, "Metrics").

The paper scores the compensated wrench (ideal zero, so its value is its error)
per axis over the no-contact samples after convergence: MAE, Max AE and Std,
before (the raw reading) and after, and MAE compensation % = 100 · (1 −
MAE_after / MAE_before). Convergence is the first sample at which the paper's
‖Δx‖ < 1e-3 holds (an estimator's ``converged_*`` flag). The RMS per axis, and
the ratio of two RMS vectors' norms (online against the offline batch fit),
are ours.

Every function takes ``(n, k)`` arrays (one column per axis, one row per
sample) and returns one value per axis; a ``(n,)`` array gives one value.
Units are those of the input (N or N·m).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def rms(values: np.ndarray) -> np.ndarray:
    """Root mean square per axis; NaN per axis when there are no rows."""
    values = np.asarray(values, dtype=float)
    if len(values) == 0:
        return np.full(values.shape[1:], np.nan)
    return np.sqrt(np.mean(values**2, axis=0))


def mae(values: np.ndarray) -> np.ndarray:
    """Mean absolute error per axis (the values are errors: ideal zero)."""
    return np.mean(np.abs(values), axis=0)


def max_ae(values: np.ndarray) -> np.ndarray:
    """Largest absolute error per axis (Max AE; the ± bounds of the paper's Table III)."""
    return np.max(np.abs(values), axis=0)


def std(values: np.ndarray) -> np.ndarray:
    """Standard deviation per axis about the axis's own mean (population, ddof = 0, as the paper's Std)."""
    return np.std(values, axis=0)


def mae_compensation_pct(mae_before: float, mae_after: float) -> float:
    """MAE compensation % = 100 · (1 − MAE_after / MAE_before); NaN when there was nothing to compensate."""
    return 100.0 * (1.0 - mae_after / mae_before) if mae_before > 0 else float("nan")


def error_stats(before: np.ndarray, after: np.ndarray, axes: Sequence[str]) -> dict[str, dict[str, float]]:
    """The paper's table (Tables I and II) per axis: MAE, Max AE and Std before (raw) and after, MAE compensation %.

    ``before`` and ``after`` are the same samples (already chosen: no contact,
    after convergence), one column per name in ``axes``.
    """
    mae_b, mae_a = mae(before), mae(after)
    max_b, max_a = max_ae(before), max_ae(after)
    std_b, std_a = std(before), std(after)
    return {
        axis: {
            "mae_before": float(mae_b[k]),
            "max_before": float(max_b[k]),
            "std_before": float(std_b[k]),
            "mae_after": float(mae_a[k]),
            "max_after": float(max_a[k]),
            "std_after": float(std_a[k]),
            "mae_comp_pct": mae_compensation_pct(float(mae_b[k]), float(mae_a[k])),
        }
        for k, axis in enumerate(axes)
    }


def scored_rows(first: int | None, values: np.ndarray, contact: np.ndarray | None = None) -> np.ndarray:
    """(n,) the rows scored: from sample ``first`` on, not ``contact``, every value in the row finite.

    ``first`` is the first converged sample for the paper's "after
    convergence" (no row when the estimator never converged: None); any other
    start (half the file) works alike. With ``contact`` None no row is set aside as contact.
    """
    n = len(values)
    if first is None:
        return np.zeros(n, dtype=bool)
    rows = (np.arange(n) >= first) & np.isfinite(values).reshape(n, -1).all(1)
    return rows if contact is None else rows & ~np.asarray(contact, dtype=bool)


def rms_after_convergence(values: np.ndarray, contact: np.ndarray | None, first: int | None) -> np.ndarray:
    """Per-axis RMS over the no-contact rows (finite) from the first convergence on; NaN if there are none."""
    return rms(values[scored_rows(first, values, contact)])


def norm_ratio(rms_values: np.ndarray, rms_reference: np.ndarray) -> float:
    """‖a‖ / ‖b‖ of two per-axis RMS vectors over the same rows (e.g. the online estimate against the batch fit)."""
    return float(np.linalg.norm(rms_values) / np.linalg.norm(rms_reference))


class RmsAfterConvergence:
    """:func:`rms_after_convergence` over a stream read in chunks: add each chunk's rows in order.

    ``first`` is the first converged row (None until one is seen) and ``value``
    the per-axis RMS over the no-contact, finite rows from it on (NaN when there
    are none); the same numbers as the whole-array function, up to the order of
    the summation.
    """

    def __init__(self, axes: int = 3):
        self.first: int | None = None
        self.rows = 0
        self._sum = np.zeros(axes)
        self._count = 0

    def add(self, values: np.ndarray, contact: np.ndarray, converged: np.ndarray) -> None:
        if self.first is None and converged.any():
            self.first = self.rows + int(np.argmax(converged))
        if self.first is not None:
            rows = scored_rows(max(self.first - self.rows, 0), values, contact)
            self._sum += np.sum(values[rows] ** 2, axis=0)
            self._count += int(rows.sum())
        self.rows += len(values)

    @property
    def value(self) -> np.ndarray:
        return np.sqrt(self._sum / self._count) if self._count else np.full(len(self._sum), np.nan)
