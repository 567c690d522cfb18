"""Reviewing recorded sessions: one session's report (summary, tables, plots, a page) and a cohort's table."""

from .figures import Contact, EstimatorReview
from .summary import DEFAULT_FORCE_LIMIT_N, SessionReview, review

__all__ = ["DEFAULT_FORCE_LIMIT_N", "Contact", "EstimatorReview", "SessionReview", "review"]
