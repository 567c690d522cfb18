"""The skill metrics' names: the keys of ``review --json``, the cohort's CSV columns and its table's words.

One row per metric: (key, words, unit). The key carries its unit (``_N``, ``_Ns``, ``_s``, ``_m``) so a CSV
column or a JSON key reads without this table; the words head the report's and the cohort page's tables.
How each is computed, and the paper it comes from, is in ``skill.py``.
"""

from __future__ import annotations

METRICS: tuple[tuple[str, str, str], ...] = (
    ("task_score", "task score", "%"),
    ("task_time_s", "task time", "s"),
    ("peak_force_N", "peak force", "N"),
    ("force_time_integral_Ns", "force–time integral", "N·s"),
    ("mean_force_rate_N_s", "mean force rate", "N/s"),
    ("max_force_rate_N_s", "max force rate", "N/s"),
    ("sparc", "smoothness (SPARC)", ""),
    ("excess_force_events", "excessive-force events", "count"),
    ("excess_force_time_s", "time above the limit", "s"),
    ("contact_time_s", "time in contact", "s"),
    ("path_length_m", "path length", "m"),
    ("following_time_s", "time following", "s"),
    ("holding_time_s", "time holding", "s"),
    ("clutching_time_s", "time clutching", "s"),
)
"""Every skill metric, in the order the report and the cohort show them."""

KEYS: tuple[str, ...] = tuple(key for key, _, _ in METRICS)
LOWER_IS_BETTER = frozenset(KEYS) - {"task_score", "sparc", "following_time_s"}
"""Metrics where a smaller value is the better skill (SPARC is negative: nearer 0 is smoother)."""


def header(key: str) -> str:
    """A metric's words with its unit, for a table's header: ``peak force (N)``."""
    _, words, unit = next(m for m in METRICS if m[0] == key)
    return f"{words} ({unit})" if unit else words
