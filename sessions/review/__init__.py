"""Reviewing recorded sessions: one session's report (summary, tables, plots, a page) and a cohort's table.

The names below are imported on first use, so a light module of this package (``skill_names``, which the
command line's parser reads) does not bring the review's numerics with it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hapticlab.sessions.review.figures import Contact, EstimatorReview
    from hapticlab.sessions.review.summary import DEFAULT_FORCE_LIMIT_N, SessionReview, review

__all__ = ["DEFAULT_FORCE_LIMIT_N", "Contact", "EstimatorReview", "SessionReview", "review"]

_HOMES = {
    "Contact": "figures",
    "EstimatorReview": "figures",
    "DEFAULT_FORCE_LIMIT_N": "summary",
    "SessionReview": "summary",
    "review": "summary",
}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value
