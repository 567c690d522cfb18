"""Reviewing recorded sessions: one session's report (summary, tables, plots, a page) and a cohort's table.

The names below are imported on first use, so a light module of this package (``skill_names``, which the
command line's parser reads) does not bring the review's numerics with it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hapticlab.core.lazy import lazy_exports

if TYPE_CHECKING:
    from hapticlab.sessions.review.figures import Contact, EstimatorReview
    from hapticlab.sessions.review.summary import DEFAULT_FORCE_LIMIT_N, SessionReview, review

__all__ = ["DEFAULT_FORCE_LIMIT_N", "Contact", "EstimatorReview", "SessionReview", "review"]

__getattr__ = lazy_exports(
    __name__,
    {
        "Contact": "hapticlab.sessions.review.figures",
        "EstimatorReview": "hapticlab.sessions.review.figures",
        "DEFAULT_FORCE_LIMIT_N": "hapticlab.sessions.review.summary",
        "SessionReview": "hapticlab.sessions.review.summary",
        "review": "hapticlab.sessions.review.summary",
    },
)
