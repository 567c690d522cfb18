"""Tools as first-class objects: the library of known tools (``library.py``), the ``[tool]`` table
(``settings.py``), and what a session does with them.

:func:`prepare` runs once, before the session is built: a named tool the library knows starts the primary
estimator from its saved state (when the estimator takes a ``warm_start`` and none is given). Its mass is not
stated from the record: identified, not weighed, it may hold a support taken in (a stated mass also turns
the pull watch off). :func:`save` runs at the session's end: the primary's parameters and state become the
tool's record, when the tool was identified and nothing held the force for a fault at the end.
"""

from __future__ import annotations

import copy
import datetime as dt
from dataclasses import asdict, dataclass, fields
from typing import Any

from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import unknown_key
from hapticlab.sessions.tools.library import ToolLibrary, ToolRecord
from hapticlab.sessions.tools.settings import ToolSettings

__all__ = [
    "ToolLibrary",
    "ToolPlan",
    "ToolRecord",
    "ToolSettings",
    "change_tool_plan",
    "prepare",
    "save",
    "tool_settings",
]


def tool_settings(config: dict[str, Any]) -> ToolSettings:
    """The validated ``[tool]`` table (no tool when it is absent)."""
    table = config.get("tool", {})
    if not isinstance(table, dict):
        raise ConfigError(f"tool: must be a table, got {table!r}")
    names = [f.name for f in fields(ToolSettings)]
    for key in table:
        if key not in names:
            raise unknown_key("tool", key, names)
    return ToolSettings(**table)


@dataclass(frozen=True)
class ToolPlan:
    """What a session does with its tool: ``name`` ("" none), the ``library``'s folder, the ``record`` it
    started from (None: unknown), and the ``warm_start`` it took from it ("" none)."""

    name: str = ""
    library: str = ""
    record: ToolRecord | None = None
    warm_start: str = ""

    def message(self) -> str:
        """What the session does with its tool, for the ``tool`` event at its start."""
        if self.record is None:
            return (
                f"tool {self.name!r} is not in the library ({self.library}): identified from the motion, saved there "
                "when the session ends"
            )
        r = self.record
        warm = "the estimator starts from its state" if self.warm_start else "the estimator starts cold"
        return (
            f"tool {self.name!r} from the library ({r.mass_kg:.3f} kg, {r.sessions} sessions, last {r.updated}): {warm}"
        )

    def resolved(self) -> dict[str, Any]:
        """The ``[tool]`` table as the recording keeps it."""
        out: dict[str, Any] = {"name": self.name, "library": self.library, "known": self.record is not None}
        if self.record is not None:
            out.update(record=asdict(self.record), warm_start=self.warm_start)
        return out


def prepare(config: dict[str, Any], takes_warm_start: bool) -> tuple[dict[str, Any], ToolPlan]:
    """The config with the named tool's record applied (a copy; the same config with no tool), and the plan.
    ``takes_warm_start``: the primary estimator has a ``warm_start`` option."""
    settings = tool_settings(config)
    library = ToolLibrary(settings.library or None)
    if not settings.name:
        return config, ToolPlan(library=str(library.folder))  # (a told change saves in this library)
    record = library.get(settings.name)
    plan = ToolPlan(settings.name, str(library.folder), record)
    if record is None:
        return config, plan
    config = copy.deepcopy(config)
    estimator = config.setdefault("estimator", {})
    state = library.state(settings.name)
    warm = ""
    if takes_warm_start and state is not None and not estimator.get("warm_start"):
        warm = estimator["warm_start"] = str(state)
    return config, ToolPlan(settings.name, str(library.folder), record, warm)


def change_tool_plan(plan: ToolPlan, name: str) -> ToolPlan:
    """The plan after the session's tool changed to ``name`` ("" unnamed: nothing read, nothing saved), in the
    same library: its record and saved state when the library knows it."""
    library = ToolLibrary(plan.library or None)
    if not name:
        return ToolPlan(library=str(library.folder))
    record = library.get(name)
    state = library.state(name) if record is not None else None
    return ToolPlan(name, str(library.folder), record, str(state or ""))


def save(
    plan: ToolPlan, params: dict[str, list[float]] | None, state: dict[str, Any] | None, estimator: str, recording: str
) -> str:
    """Write the session's tool back to its library: the event's message (what was saved, or why not)."""
    record = ToolRecord.from_params(
        plan.name,
        params or {},
        estimator=estimator,
        updated=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        sessions=(plan.record.sessions if plan.record else 0) + 1,
        recording=recording,
    )
    if record is None:
        return ""
    path = ToolLibrary(plan.library).save(record, state)
    cog = ", ".join(f"{v * 1e3:.1f}" for v in record.cog_S)
    return f"tool {plan.name!r} saved to {path}: {record.mass_kg:.3f} kg, centre of gravity ({cog}) mm in S"
