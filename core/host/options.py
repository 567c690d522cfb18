"""One option toolkit: every config reader checks its values with these, in one error style.

A check takes the key (for the message) and the value, and returns the value checked and
converted (a float, an int, a read-only numpy array) or raises :class:`OptionError` naming the key:
``noise_force: must be a number or 3 numbers, each >= 0, got -1``. A reader that knows where the
key sits prefixes it (``estimator.noise_force: ...``, ``world.tool.mass: ...``) and the command
line prints that one line with exit status 2. The words after ``must be`` say what the option
accepts; :func:`accepts` gives them for the reference pages.

Who uses it: the plugins' typed options (a frozen dataclass per plugin whose ``__post_init__``
runs these checks once), the simulated world's ``[world]`` tables and the session's own tables
(``[session]``, ``[haptic]``, ``[teleop]``).

Booleans are never numbers here (TOML's ``true`` is not 1), NaN is never a number, and a limit
is printed with ``:g`` so the message shows what the user typed. numpy scalars and arrays count
as numbers (a record built in Python may hold them).
"""

from __future__ import annotations

import difflib
import ipaddress
import math
import re
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import TYPE_CHECKING, Any

from hapticlab.core.errors import ConfigError

if TYPE_CHECKING:  # imported where used: the plugin host, and so every command's start-up, reads this module
    import numpy as np

Check = Callable[[str, Any], Any]
"""A check: (key, value) -> the checked value, or OptionError."""


class OptionError(ValueError):
    """One option's value is wrong: ``key: problem``.

    A ``ValueError`` so a plugin's constructor can raise it and the host (which knows the table)
    names the full key; :meth:`under` does that.
    """

    def __init__(self, key: str, problem: str):
        self.key, self.problem = key, problem
        super().__init__(f"{key}: {problem}")

    def under(self, where: str) -> ConfigError:
        """The same error with the table in front: ``where.key: problem``."""
        return ConfigError(f"{where}.{self.key}: {self.problem}" if where else str(self))


def is_number(value: Any) -> bool:
    """An int or float (numpy's too) that is not a bool and not NaN (inf passes: the range checks decide)."""
    import numpy as np

    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and not math.isnan(value)
    )


def _range_words(
    minimum: float | None, above: float | None, maximum: float | None = None, below: float | None = None
) -> str:
    words = []
    if minimum is not None:
        words.append(f">= {minimum:g}")
    if above is not None:
        words.append(f"> {above:g}")
    if maximum is not None:
        words.append(f"<= {maximum:g}")
    if below is not None:
        words.append(f"< {below:g}")
    return " and ".join(words)


def _in_range(
    x: float, minimum: float | None, above: float | None, maximum: float | None = None, below: float | None = None
) -> bool:
    return (
        (minimum is None or x >= minimum)
        and (above is None or x > above)
        and (maximum is None or x <= maximum)
        and (below is None or x < below)
    )


def number(
    key: str,
    value: Any,
    *,
    minimum: float | None = None,
    above: float | None = None,
    maximum: float | None = None,
    below: float | None = None,
    finite: bool = True,
    hint: str = "",
) -> float:
    """A number (int or float, not a bool, not NaN; finite unless ``finite=False``) within the limits given.

    ``minimum``/``maximum`` are inclusive, ``above``/``below`` exclusive; ``hint`` ends the message
    (e.g. the unit, or what else the option accepts: ``" or 'auto'"``).
    """
    ok = is_number(value) and (math.isfinite(value) or not finite)
    if not ok or not _in_range(value, minimum, above, maximum, below):
        limits = _range_words(minimum, above, maximum, below)
        what = ("a finite number" if finite else "a number") + (f" {limits}" if limits else "")
        raise OptionError(key, f"must be {what}{hint}, got {value!r}")
    return float(value)


def integer(key: str, value: Any, *, minimum: int | None = None, maximum: int | None = None, hint: str = "") -> int:
    """A whole number (an int, not a bool) within the inclusive limits given."""
    import numpy as np

    whole = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not whole or not _in_range(value, minimum, None, maximum):
        limits = _range_words(minimum, None, maximum)
        raise OptionError(key, f"must be a whole number{' ' + limits if limits else ''}{hint}, got {value!r}")
    return int(value)


def boolean(key: str, value: Any) -> bool:
    """true or false (not 0 or 1)."""
    if not isinstance(value, bool):
        raise OptionError(key, f"must be true or false, got {value!r}")
    return value


def text(key: str, value: Any, *, hint: str = "") -> str:
    """A string."""
    if not isinstance(value, str):
        raise OptionError(key, f"must be a string{hint}, got {value!r}")
    return value


def choice(key: str, value: Any, choices: Sequence[Any], *, hint: str = "") -> Any:
    """One of ``choices`` (compared with ==, so a string option also refuses a number)."""
    if isinstance(value, bool) or value not in choices or not isinstance(value, type(choices[0])):
        names = (
            ", ".join(repr(c) for c in choices[:-1]) + f" or {choices[-1]!r}" if len(choices) > 1 else repr(choices[0])
        )
        raise OptionError(key, f"must be {names}{hint}, got {value!r}")
    return value


def _finite_array(value: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """``value`` (nested lists, tuples or a numpy array of numbers) as a new float array of ``shape``,
    or None when it is not that many finite numbers (bools and strings are not numbers)."""
    import numpy as np

    if isinstance(value, np.ndarray):
        if value.shape != shape or value.dtype.kind not in "iuf" or not np.isfinite(value).all():
            return None
        return value.astype(float)
    if not shape:
        return np.array(float(value)) if is_number(value) and math.isfinite(value) else None
    if not isinstance(value, (list, tuple)) or len(value) != shape[0]:
        return None
    items = [_finite_array(item, shape[1:]) for item in value]
    if any(item is None for item in items):
        return None
    return np.array(items, dtype=float)


def vector(
    key: str,
    value: Any,
    *,
    size: int = 3,
    broadcast: bool = False,
    minimum: float | None = None,
    above: float | None = None,
    hint: str = "",
) -> np.ndarray:
    """``size`` finite numbers (with ``broadcast``, one number stands for all), each within the limits;
    a read-only float array."""
    import numpy as np

    array = _finite_array(value, (size,))
    if array is None and broadcast and is_number(value) and math.isfinite(value):
        array = np.full(size, float(value))
    if array is None or not all(_in_range(float(v), minimum, above) for v in array):
        limits = _range_words(minimum, above)
        what = f"a number or {size} numbers" if broadcast else f"{size} numbers"
        raise OptionError(key, f"must be {what}{', each ' + limits if limits else ''}{hint}, got {value!r}")
    array.setflags(write=False)
    return array


def rated_range(key: str, value: Any) -> np.ndarray:
    """(3,) a sensor's rated range per axis, N or N·m, from a number or 3 (each above 0); unchecked (inf) when
    ``value`` is None."""
    import numpy as np

    return np.full(3, np.inf) if value is None else np.array(vector(key, value, size=3, broadcast=True, above=0))


def matrix(key: str, value: Any, *, shape: tuple[int, int] = (3, 3), hint: str = "") -> np.ndarray:
    """A matrix of finite numbers given as rows (``[[...], [...], [...]]``); a read-only float array."""
    array = _finite_array(value, shape)
    if array is None:
        rows, cols = shape
        raise OptionError(key, f"must be a {rows}x{cols} matrix ({rows} rows of {cols} numbers){hint}, got {value!r}")
    array.setflags(write=False)
    return array


_HOSTNAME = re.compile(
    r"^(?=.{1,253}$)[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*$"
)


def host_address(key: str, value: Any) -> str:
    """An IP address or a host name (RFC 1123 labels; all digits and dots is an IPv4 address or nothing)."""
    if isinstance(value, str):
        try:
            ipaddress.ip_address(value)
            return value
        except ValueError:
            if _HOSTNAME.match(value) and not value.replace(".", "").isdigit():
                return value
    raise OptionError(key, f"must be an IP address or a host name, got {value!r}")


def listen_address(key: str, host: str, *, allow_network: bool = False, exposes: str = "it") -> str:
    """``host``, an address to listen on: a loopback one (127.0.0.0/8, ::1, ``localhost``), or any with
    ``allow_network`` (the user asked for the network with ``--allow-network``). A host name other than
    ``localhost`` counts as the network (where it points is not this machine's to say). OptionError
    otherwise, saying what the address would expose (``exposes``)."""
    name = host.strip("[]")
    try:
        loopback = name == "localhost" or ipaddress.ip_address(name).is_loopback
    except ValueError:
        loopback = False
    if loopback or allow_network:
        return host
    raise OptionError(
        key,
        f"must be a loopback address (127.0.0.x, ::1, localhost) unless --allow-network is given, got {host!r}: "
        f"it would serve {exposes} to anyone on the network",
    )


def check_fields(record: Any, checks: Mapping[str, Check]) -> None:
    """Run ``checks`` on a frozen record's fields (from its ``__post_init__``), keeping what they return
    (the converted value: a float, a read-only array); OptionError naming the field."""
    for name, check_field in checks.items():
        object.__setattr__(record, name, check_field(name, getattr(record, name)))


def check(function: Callable[..., Any], **limits: Any) -> Check:
    """A table's check from a toolkit function and its limits: ``check(number, above=0)``."""
    return partial(function, **limits) if limits else function


class _Probe:
    """A value no check accepts: its refusal says what the check does accept."""

    def __repr__(self) -> str:
        return "<probe>"


def accepts(check: Check) -> str:
    """What a check accepts, in its messages' words: ``accepts(check(number, above=0))`` is
    ``"a finite number > 0"`` (for reference pages generated from the code)."""
    try:
        check("key", _Probe())
    except OptionError as exc:
        return exc.problem.removeprefix("must be ").removesuffix(", got <probe>")
    raise TypeError(f"{check!r} accepts anything: not a check of this toolkit")


def unknown_key(where: str, key: str, known: Sequence[str]) -> ConfigError:
    """The error for a key a table does not have, with the closest known key and the known ones."""
    names = sorted(known)
    close = difflib.get_close_matches(key, names, n=1)
    hint = f"; did you mean {close[0]}?" if close else ""
    listed = ", ".join(names) or "none"
    return ConfigError(f"{where + '.' if where else ''}{key}: unknown option{hint}; known options: {listed}")


def read_table(where: str, table: Any, checks: Mapping[str, Check]) -> dict[str, Any]:
    """Every key of a config table through its check (the full key ``where.key`` in every message);
    an unknown key or a table that is not one is a ConfigError."""
    if not isinstance(table, Mapping):
        raise ConfigError(f"{where}: must be a table, got {table!r}")
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in checks:
            raise unknown_key(where, key, list(checks))
        try:
            out[key] = checks[key](f"{where}.{key}", value)
        except OptionError as exc:
            raise ConfigError(str(exc)) from None
    return out
