"""A fault an emulator injects at a set time: ``--fault KIND@SECONDS[:ARG]`` on its command line.

Each emulator subclasses :class:`ScheduledFault` with the kinds it knows (``KINDS``), an example for its
messages (``EXAMPLE``) and, in its docstring, what each kind does and what ``ARG`` means there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Self


@dataclass(frozen=True)
class ScheduledFault:
    """A fault of ``kind`` at ``at`` s, with its argument ``arg`` (None: the kind's default)."""

    KINDS: ClassVar[tuple[str, ...]] = ()
    EXAMPLE: ClassVar[str] = "crc@5:3"

    kind: str
    at: float
    arg: float | None = None

    @classmethod
    def parse(cls, text: str) -> Self:
        """``KIND@SECONDS[:ARG]``; ValueError naming the ``--fault`` given and what it should be."""
        kind, _, rest = text.partition("@")
        when, _, arg = rest.partition(":")
        try:
            fault = cls(kind.strip(), float(when), float(arg) if arg else None)
        except ValueError:
            raise ValueError(f"--fault {text!r}: expected KIND@SECONDS[:ARG], e.g. {cls.EXAMPLE}") from None
        if fault.kind not in cls.KINDS:
            raise ValueError(f"--fault {text!r}: unknown kind {fault.kind!r}; known: {', '.join(cls.KINDS)}")
        if not (fault.at >= 0 and (fault.arg is None or fault.arg >= 0)):
            raise ValueError(f"--fault {text!r}: times and counts must be >= 0")
        return fault
