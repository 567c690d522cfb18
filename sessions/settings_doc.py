"""The tables of ``docs/sessions.md``, generated from the code: every session setting, what it accepts,
its default and its meaning.

What a key accepts is its check's own words (``options.accepts``), its default the record's or the
factory's, its meaning the record's docstring (its ``Attributes:`` or ``Parameters`` entry), so the page
cannot drift from the code. The prose around the tables is written by hand in the page; each table
sits between ``<!-- generated: ID -->`` and ``<!-- end generated -->``, and running this module
rewrites them in place::

    python -m hapticlab.sessions.settings_doc [docs/sessions.md]

``tests/sessions/test_sessions_doc.py`` fails when the page is not what this module writes, or when a
setting the code accepts is missing from it.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core.host.options import Check, accepts
from hapticlab.core.host.registry import Registry, option_types
from hapticlab.plugins.simworld import config as world
from hapticlab.plugins.simworld.faults import DEFAULT_DURATION_S, Fault
from hapticlab.plugins.simworld.params import RobotParams, SensorParams, ToolParams
from hapticlab.sessions.settings import HapticSettings, SessionSettings, TeleopSettings
from hapticlab.sessions.tasks.settings import TaskSettings
from hapticlab.sessions.tools.settings import ToolSettings

PAGE = Path(__file__).resolve().parents[1] / "docs" / "sessions.md"
"""The page in a source checkout (the package's root is the repository's)."""

PLUGIN_DOCS = {
    ("sensor", "sim"): "`plugins/sensors/sim.py` (`SimSensor`); the world it reads: `[world]` below",
    ("sensor", "netft"): '[devices.md](devices.md), "ATI Net F/T"',
    ("sensor", "bota"): '[devices.md](devices.md), "Bota Systems serial sensors"',
    ("sensor", "robotiq_ft300"): '[devices.md](devices.md), "Robotiq FT 300"',
    ("kinematics", "sim"): "`plugins/kinematics/sim.py` (`SimKinematics`); the world it reads: `[world]` below",
    ("kinematics", "ur_rtde"): '[devices.md](devices.md), "Universal Robots arm over RTDE"',
    ("kinematics", "urdf"): '[devices.md](devices.md), "URDF kinematics"',
    ("estimator", "rls"): '[estimators.md](estimators.md), "rls" (`RLSOptions`)',
    ("estimator", "kalman"): '[estimators.md](estimators.md), "kalman" (`KalmanOptions`)',
    ("estimator", "batch"): '[estimators.md](estimators.md), "batch" (`BatchOptions`)',
    ("haptic_output", "null"): "`plugins/haptics/null.py` (`NullHaptic`)",
    ("haptic_output", "sim"): "`plugins/haptics/sim_master.py` (`SimMaster`): a simulated master with a hand on it",
    ("haptic_output", "serial"): '[devices.md](devices.md), "Serial haptic masters"',
    ("haptic_output", "hid"): '[devices.md](devices.md), "RawHID haptic masters"',
}
"""Where each built-in plugin's options are documented (a registered plugin missing here fails the test)."""
PLUGIN_KINDS = {"sensor": "sensor", "kinematics": "kinematics", "estimator": "estimator", "haptic_output": "haptic"}
"""Plugin kind -> the table that names it (an estimator also in ``[shadows.<label>]``)."""

EXTRA_MEANINGS = {
    ("world", "tool"): "the tool: `[world.tool]` (below)",
    ("world", "sensor"): "the F/T sensor: `[world.sensor]` (below)",
    ("world", "robot"): "the robot's installation: `[world.robot]` (below)",
    ("world", "motion"): "what the flange does: `[world.motion]` (below)",
    ("world", "contacts"): "contact events: `[[world.contacts]]` (below)",
    ("world", "faults"): "injected faults: `[[world.faults]]` (below)",
    ("world", "seed"): "seed of every random stream of the world (noise, drift, waypoints)",
    ("world", "inertia"): "include the tool's inertial wrench (false: the paper's static model exactly)",
    ("world.tool", "inertia_diag"): "the principal moments of `inertia` (its diagonal; give one of the two), kg·m²",
}
"""Meanings no record docstring holds (the keys that are not one record field)."""


# --------------------------------------------------------------------------- docstrings

_ENTRY = re.compile(r"^(\s*)([A-Za-z_]\w*(?:, [A-Za-z_]\w*)*) ?: (.*)$")
_SECTIONS = ("Attributes:", "Args:", "Parameters")


def field_docs(cls: type) -> dict[str, str]:
    """``name -> meaning`` from the ``Attributes:``/``Args:`` (Google) or ``Parameters`` (numpy) sections
    of a class's docstring and its bases' (an entry "as X" keeps the base's meaning)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        lines = inspect.cleandoc(klass.__dict__.get("__doc__") or "").splitlines()
        indent: int | None = None
        names: list[str] = []
        section = False
        for line in lines:
            stripped = line.strip()
            if stripped in _SECTIONS:
                section, indent, names = True, None, []
                continue
            if not section or set(stripped) == {"-"}:
                continue
            depth = len(line) - len(line.lstrip())
            entry = _ENTRY.match(line)
            if entry and (indent is None or depth == indent):
                indent = depth
                names = entry.group(2).split(", ")
                for name in names:
                    if not (entry.group(3).startswith("as ") and name in docs):
                        docs[name] = entry.group(3)
            elif stripped and indent is not None and depth > indent and names:
                for name in names:
                    docs[name] += " " + stripped
            else:
                section = False
    return {name: _markdown(text) for name, text in docs.items()}


def _markdown(text: str) -> str:
    text = re.sub(r":(?:class|data|func|meth|attr):`~?([^`]+)`", r"`\1`", text)
    text = re.sub(r"^\(\d+(?:, \d+)?\) ", "", text.strip())  # the shape: "accepts" says it
    return text.replace("``", "`").replace("|", "\\|")


# --------------------------------------------------------------------------- values


def toml_value(value: Any) -> str:
    """A default as it would be written in TOML (``inf`` for for ever, ``none`` for none)."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (int, np.integer)):
        return str(value)
    if isinstance(value, (float, np.floating)):
        return "inf" if math.isinf(value) else f"{value:g}"
    if isinstance(value, (tuple, list, np.ndarray)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return str(value)


Row = tuple[str, str, str, str]
"""(key, accepts, default, meaning) of one setting."""


def _record_defaults(cls: type) -> dict[str, Any]:
    return {f.name: getattr(cls(), f.name) for f in dataclasses.fields(cls)}


def settings_rows(cls: Any) -> list[Row]:
    """The rows of a host table (``SessionSettings``, ...): its fields, its CHECKS, its docstring."""
    defaults, meanings = _record_defaults(cls), field_docs(cls)
    return [(name, accepts(check), toml_value(defaults[name]), meanings[name]) for name, check in cls.CHECKS.items()]


def record_rows(
    where: str,
    checks: Mapping[str, Check],
    record: type,
    fields: Mapping[str, str] | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> list[Row]:
    """The rows of a ``[world]`` table whose keys fill ``record`` (``fields``: key -> record field)."""
    meanings = field_docs(record)
    if defaults is None:
        signature = inspect.signature(record)
        defaults = {
            name: "required" if p.default is inspect.Parameter.empty else p.default
            for name, p in signature.parameters.items()
        }
    rows = []
    for key, check in checks.items():
        name = (fields or {}).get(key, key)
        default = defaults.get(name, "")
        shown = default if isinstance(default, str) and default in ("required", "") else toml_value(default)
        rows.append((key, accepts(check), shown, EXTRA_MEANINGS.get((where, key), meanings.get(name, ""))))
    return rows


def _world_rows() -> list[Row]:
    rows = []
    for key, check in world.WORLD_OPTIONS.items():
        try:
            rows.append(
                (key, accepts(check), toml_value(getattr(world.WorldSpec(), key)), EXTRA_MEANINGS[("world", key)])
            )
        except TypeError:  # a sub-table, read by its own reader
            shown = "a list of tables" if key in ("contacts", "faults") else "a table"
            rows.append((key, shown, "", EXTRA_MEANINGS[("world", key)]))
    return rows


def _tool_rows() -> list[Row]:
    defaults = _record_defaults(ToolParams)
    by_key = {world.TOOL_FIELDS[key]: defaults[world.TOOL_FIELDS[key]] for key in world.TOOL_OPTIONS}
    rows = record_rows("world.tool", world.TOOL_OPTIONS, ToolParams, world.TOOL_FIELDS, by_key)
    diagonal = toml_value(np.diag(defaults["inertia_S"]))
    return [(k, a, diagonal if k == "inertia_diag" else d, m) for k, a, d, m in rows]


def _fault_rows() -> list[Row]:
    rows = record_rows("world.faults", world.FAULT_OPTIONS, Fault)
    others = ", ".join(f"{kind}: {toml_value(s)}" for kind, s in DEFAULT_DURATION_S.items())
    return [(k, a, f"1 ({others})" if k == "duration" else d, m) for k, a, d, m in rows]


def motion_aliases() -> dict[str, str]:
    """``[world.motion] script`` names that are another name of an earlier script (``indentation``: ``hold``)."""
    first: dict[type, str] = {}
    for script, cls in world.MOTION_SCRIPTS.items():
        first.setdefault(cls, script)
    return {script: first[cls] for script, cls in world.MOTION_SCRIPTS.items() if first[cls] != script}


def tables() -> dict[str, list[Row]]:
    """Every generated table: id -> rows (the id is the table's TOML name, ``world.motion.servo`` for a
    script's options)."""
    out: dict[str, list[Row]] = {
        "session": settings_rows(SessionSettings),
        "haptic": settings_rows(HapticSettings),
        "teleop": settings_rows(TeleopSettings),
        "task": settings_rows(TaskSettings),
        "tool": settings_rows(ToolSettings),
        "world": _world_rows(),
        "world.tool": _tool_rows(),
        "world.sensor": record_rows(
            "world.sensor", world.SENSOR_OPTIONS, SensorParams, world.SENSOR_FIELDS, _record_defaults(SensorParams)
        ),
        "world.robot": record_rows(
            "world.robot", world.ROBOT_OPTIONS, RobotParams, world.ROBOT_FIELDS, _record_defaults(RobotParams)
        ),
    }
    for script, checks in world.MOTION_OPTIONS.items():
        if script not in motion_aliases():
            out[f"world.motion.{script}"] = record_rows("world.motion", checks, world.MOTION_SCRIPTS[script])
    for kind, checks in world.CONTACT_OPTIONS.items():
        out[f"world.contacts.{kind}"] = record_rows("world.contacts", checks, world.CONTACT_KINDS[kind])
    out["world.faults"] = _fault_rows()
    return out


def builtin_plugins(registry: Registry, kind: str) -> list[str]:
    """The names of hapticlab's own plugins of a kind (third-party ones document themselves)."""
    return [n for n in registry.names(kind) if registry.get(kind, n).factory.__module__.startswith("hapticlab.")]


def plugin_rows(registry: Registry | None = None) -> list[Row]:
    """(table, name, where its options are documented, its options) of every built-in plugin."""
    registry = registry or Registry()
    contexts = set(registry.names("context"))
    rows = []
    for kind, table in PLUGIN_KINDS.items():
        for name in builtin_plugins(registry, kind):
            options = sorted(set(option_types(registry.get(kind, name).factory)) - contexts)
            where = PLUGIN_DOCS.get((kind, name), "its package's documentation")
            shown = f"[{table}]" + (" or [shadows.<label>]" if kind == "estimator" else "")
            rows.append((f"`{shown}`", f"`{name}`", where, ", ".join(f"`{o}`" for o in options) or "none"))
    return rows


# --------------------------------------------------------------------------- the page


def markdown_table(rows: list[Row], header: Row = ("key", "accepts", "default", "meaning")) -> str:
    def cells(row: Row) -> str:
        return "| " + " | ".join(c if c else " " for c in row) + " |"

    keyed = [(f"`{k}`" if not k.startswith("`") else k, a, d, m) for k, a, d, m in rows]
    return "\n".join([cells(header), "|" + "---|" * len(header), *(cells(r) for r in keyed)])


def blocks() -> dict[str, str]:
    """Every generated block of the page: id -> markdown."""
    out = {name: markdown_table(rows) for name, rows in tables().items()}
    out["plugins"] = markdown_table(plugin_rows(), ("table", "name", "its options are documented in", "options"))
    return out


_BLOCK = re.compile(r"(<!-- generated: ([\w.]+) -->\n)(.*?)(<!-- end generated -->)", re.S)


def render(page: str, made: Mapping[str, str] | None = None) -> str:
    """The page with every generated block rewritten (an id the code does not know is left as is)."""
    made = blocks() if made is None else made

    def block(match: re.Match[str]) -> str:
        ident = match.group(2)
        body = made.get(ident)
        return match.group(0) if body is None else f"{match.group(1)}{body}\n{match.group(4)}"

    return _BLOCK.sub(block, page)


def block_ids(page: str) -> Iterator[tuple[str, str]]:
    """(id, markdown) of each generated block of the page."""
    for match in _BLOCK.finditer(page):
        yield match.group(2), match.group(3)


def main(argv: list[str] | None = None) -> int:
    """Rewrite the page's generated blocks (the page given, else ``docs/sessions.md``)."""
    args = sys.argv[1:] if argv is None else argv
    path = Path(args[0]) if args else PAGE
    page = path.read_text(encoding="utf-8")
    new = render(page)
    if new != page:
        path.write_text(new, encoding="utf-8")
        print(f"{path}: generated tables rewritten")
    else:
        print(f"{path}: current")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
