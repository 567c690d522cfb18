"""The command line's error policy: a user's mistake is one line, a bug a traceback.

A user's mistake is a :class:`~hapticlab.core.errors.UserError` (a bad file,
row, column, key or value; every hapticlab error meant for the user derives
from it) or an ``OSError`` about a path the user gave (it carries the file
name: a missing input, a folder where a file was expected, no permission).
Anything else (a plain ``ValueError`` from numpy, a ``KeyError`` in our code) is
a bug and is not caught.
"""

from __future__ import annotations

from hapticlab.core.errors import UserError


def is_user_error(exc: BaseException | None) -> bool:
    """True when ``exc`` is the user's to fix (printed as one line, exit status 2); False for None (no cause)."""
    if isinstance(exc, UserError):
        return True
    return isinstance(exc, OSError) and exc.filename is not None


def one_line(exc: BaseException) -> str:
    """The error as one line: the message, or for an ``OSError`` the path and what is wrong with it."""
    if isinstance(exc, OSError) and not isinstance(exc, UserError) and exc.filename is not None:
        what = exc.strerror or type(exc).__name__
        return f"{exc.filename}: {what[0].lower() + what[1:]}"
    return " ".join(str(exc).split()) or type(exc).__name__
