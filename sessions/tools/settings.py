"""The ``[tool]`` table: which tool the sensor carries, and where the library of known tools is."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from hapticlab.core.host.options import Check, OptionError, check_fields, text
from hapticlab.sessions.tools.library import NAME


def _name(key: str, value: Any) -> str:
    """A tool's name (``library.NAME``), or "" for none."""
    value = text(key, value, hint=" (a tool name: letters, digits, '_', '.', '-', up to 64)")
    if value and not NAME.fullmatch(value):
        raise OptionError(key, f"must be a tool name (letters, digits, '_', '.', '-', up to 64), got {value!r}")
    return value


@dataclass(frozen=True)
class ToolSettings:
    """The ``[tool]`` table (no tool named when ``name`` is empty).

    Attributes:
        name: the tool on the sensor, as the library knows it (``hapticlab tool list``). Known: the session's
            estimator starts from its saved state (where it takes a ``warm_start``), so the force is on from the
            first second (its identified mass is not stated: ``haptic.tool_mass`` is for a weighed one). Either
            way the session writes the tool back when it ends with the tool identified and nothing holding the
            force. ``""``: no tool named, nothing read or written.
        library: the folder of the tool library; ``""``: ``$XDG_CONFIG_HOME/hapticlab/tools``
            (``~/.config/hapticlab/tools``).
    """

    name: str = ""
    library: str = ""

    CHECKS: ClassVar[Mapping[str, Check]] = {"name": _name, "library": lambda key, value: text(key, value)}

    def __post_init__(self) -> None:
        try:
            check_fields(self, self.CHECKS)
        except OptionError as exc:
            raise exc.under("tool") from None
