"""The one line between a user's mistake and a bug in hapticlab.

A :class:`UserError` is something the person at the keyboard can fix: a bad
file, row, column, config key or value, a path that cannot be written. The
command line prints it as one line naming the problem and exits with status 2.
Anything else that escapes (a ``ValueError`` from numpy, a ``KeyError`` in our
code) is a bug in hapticlab and keeps its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """A mistake the user can fix; the message names it (file, row, column, key or value)."""


class OutputExistsError(UserError, FileExistsError):
    """An output path already holds a file: nothing recorded is overwritten unless the user says so."""


class PluginError(UserError):
    """A plugin could not be found, registered or built; the message names it."""


class ConfigError(PluginError):
    """A configuration value is wrong; the message names the key."""
