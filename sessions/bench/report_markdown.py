"""Markdown for ``docs/results.md``: numbers as the page prints them, and tables."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any

AXES_F = ("fx", "fy", "fz")
AXES_T = ("tx", "ty", "tz")


def num(value: Any, digits: int = 3) -> str:
    """A number with ``digits`` decimals; None and NaN (JSON's null) as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.{digits}f}"


def vec(values: Iterable[Any] | None, digits: int = 3) -> str:
    """``0.120, 0.121, 0.060``; a dash when there is nothing."""
    values = list(values or [])
    return ", ".join(num(v, digits) for v in values) if values else "–"


def norm(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values))


def table(headers: Sequence[str], rows: Iterable[Sequence[Any]], align: str = "lr") -> list[str]:
    """A Markdown table; ``align`` has an ``l`` (left) or ``r`` (right: numbers) per column, the last repeated."""
    align = align.ljust(len(headers), align[-1])
    out = ["| " + " | ".join(headers) + " |"]
    out.append("|" + "|".join(":---" if a == "l" else "---:" for a in align) + "|")
    out += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return out + [""]
