"""Rendering for the terminal: numbers as a person reads them, rich consoles, JSON without NaN."""

from __future__ import annotations

from rich.console import Console

err = Console(stderr=True)
"""Progress, notes and summaries go to stderr; stdout carries results a script can read."""


def wide_console(width: int = 120) -> Console:
    """A console at least ``width`` columns wide, for tables that must not wrap."""
    return Console(width=max(Console().width, width))


def fmt(value, digits: int = 3) -> str:
    return "–" if value is None or value != value else f"{value:.{digits}f}"


def vec(values, digits: int = 3) -> str:
    return "[" + ", ".join(fmt(v, digits) for v in values) + "]"


def finite_json(value):
    """NaN and infinities become null (JSON has no NaN)."""
    if (isinstance(value, float) and value != value) or value in (float("inf"), float("-inf")):
        return None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [finite_json(v) for v in value]
    return value
