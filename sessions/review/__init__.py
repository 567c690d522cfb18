"""Reviewing recorded sessions: one session's report (summary, tables, plots, a page) and a cohort's table."""

from hapticlab.sessions.review.figures import Contact, EstimatorReview
from hapticlab.sessions.review.summary import DEFAULT_FORCE_LIMIT_N, SessionReview, review

__all__ = ["DEFAULT_FORCE_LIMIT_N", "Contact", "EstimatorReview", "SessionReview", "review"]
