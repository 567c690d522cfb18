"""Session configuration: TOML presets and files, ``--set`` overrides, the tables a session has.

A session config is a TOML document with these tables (every one optional;
missing tables take the ``demo`` preset's values only when you start from it):

``[session]``   duration, realtime pacing, loop rate, output path
``[world]``     the simulated world (the ``world`` context of the simworld plugin,
                used by the ``sim`` sensor and kinematics)
``[sensor]``    ``name`` of a registered sensor plus its options
``[kinematics]`` ``name`` of a registered kinematics source plus its options
``[estimator]`` ``name`` of the estimator that drives the haptics plus its options
``[haptic]``    ``name`` of a haptic output plus its options and the safety limits
``[teleop]``    teleoperation: the master's handle moves the robot (``sessions/live/teleop.py``)
``[shadows.<label>]`` more estimators run side by side on the same samples and
                recorded on ``/estimator/<label>`` (``name`` defaults to the label)

The host's own tables (``[session]``, ``[haptic]``'s limits, ``[teleop]``) are read by
``sessions/settings.py``; every setting is listed in ``docs/sessions.md``. Errors are
``ConfigError`` with one line naming the key.
"""

from __future__ import annotations

import copy
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from hapticlab.core.errors import ConfigError
from hapticlab.sessions.settings import HAPTIC_SAFETY_KEYS

MAX_SESSION_FILE_BYTES = 1 << 20
"""A session file is read up to 1 MiB (the presets are ~2 kB): anything larger is not one."""

TABLES = ("session", "sensor", "kinematics", "estimator", "haptic", "teleop", "task", "tool", "shadows")
"""The host's own tables; a plugin's context (``register_contexts``, e.g. ``world``) adds its own."""
MAX_NESTING = 32
"""Tables and arrays nest at most this deep in a session config (the presets: 4): deeper is no session, and
would exhaust the recursion of every reader after the parser (a deep copy, the checks)."""
PLUGIN_TABLES = {"sensor": "sensor", "kinematics": "kinematics", "estimator": "estimator", "haptic": "haptic_output"}


def preset_names() -> list[str]:
    """Names of the presets shipped with hapticlab."""
    folder = resources.files("hapticlab.sessions") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_config(session: str | None) -> tuple[dict[str, Any], str]:
    """The raw config of a preset name or a TOML path, and where it came from."""
    session = session or "demo"
    path = Path(session)
    # a preset name unless it looks like a path (a folder named "demo" is no session)
    if session.endswith(".toml") or "/" in session or (path.is_file() and session not in preset_names()):
        if not path.is_file():
            what = "not a regular file (a folder, a device or a FIFO)" if path.exists() else "no such session file"
            raise ConfigError(f"{session}: {what}")
        text, origin = read_session_file(path), str(path)
    else:
        if session not in preset_names():
            raise ConfigError(
                f"unknown session {session!r}: not a file, and not a preset ({', '.join(preset_names())})"
            )
        text = (resources.files("hapticlab.sessions") / "presets" / f"{session}.toml").read_text("utf-8")
        origin = f"preset:{session}"
    try:
        config = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{origin}: invalid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise ConfigError(f"{origin}: invalid TOML: arrays or tables nested too deeply") from None
    if nesting_depth(config) > MAX_NESTING:  # dotted keys and [a.b.c] headers nest without recursing
        raise ConfigError(f"{origin}: tables or arrays nested more than {MAX_NESTING} deep: not a session file")
    return config, origin


def nesting_depth(value: Any) -> int:
    """How deep tables and arrays nest in ``value`` (a scalar: 0), counted without recursion, stopping
    past ``MAX_NESTING``."""
    deepest, todo = 0, [(value, 0)]
    while todo and deepest <= MAX_NESTING:
        node, depth = todo.pop()
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else None
        if children is not None:
            deepest = max(deepest, depth + 1)
            todo.extend((child, depth + 1) for child in children)
    return deepest


def read_session_file(path: Path) -> str:
    """A session file's text: UTF-8 (as TOML is), at most ``MAX_SESSION_FILE_BYTES``; ConfigError naming the
    file and, for a byte that is not UTF-8, its offset, line and column."""
    with path.open("rb") as f:
        data = f.read(MAX_SESSION_FILE_BYTES + 1)
    if len(data) > MAX_SESSION_FILE_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_SESSION_FILE_BYTES // 1024} KiB: not a session file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = data.rfind(b"\n", 0, exc.start) + 1
        line, column = data.count(b"\n", 0, exc.start) + 1, exc.start - line_start + 1
        raise ConfigError(
            f"{path}: not UTF-8 text (TOML is): byte {exc.start} (line {line}, column {column}) "
            f"is 0x{data[exc.start]:02x}"
        ) from None


def parse_value(text: str, key: str = "") -> Any:
    """A ``--set`` value: TOML syntax when it parses (2, 1.5, true, [1, 2], "x"), else a bare string."""
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise ConfigError(f"--set {key}: arrays or tables nested too deeply") from None
    if nesting_depth(value) > MAX_NESTING:
        raise ConfigError(f"--set {key}: arrays or tables nested more than {MAX_NESTING} deep")
    return value


def apply_overrides(config: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``--set key.path=value`` overrides (TOML values) to a copy of the config."""
    settings = {}
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item!r}: expected key=value, e.g. estimator.name=batch")
        settings[key.strip()] = parse_value(value, key.strip())
    return apply_settings(config, settings)


def apply_settings(config: dict[str, Any], settings: dict[str, Any]) -> dict[str, Any]:
    """Set ``{"dotted.key": value}`` in a copy of the config (the Python form of ``--set``).

    Setting a plugin table's ``name`` to another plugin drops the options the
    file gave the old one (they belong to it), keeping the other settings, so
    ``estimator.name = "kalman"`` works on any preset. Setting ``estimator.name``
    to an estimator the file runs as a shadow of the same label (the presets'
    ``[shadows.rls]``) promotes that shadow: it becomes the primary, with the
    options the file gave it, and no longer runs beside itself.
    """
    config = copy.deepcopy(config)
    for key, value in settings.items():
        table, _, rest = key.strip().partition(".")
        if (
            rest == "name"
            and table in PLUGIN_TABLES
            and isinstance(config.get(table), dict)
            and config[table].get("name") != value
        ):
            kept = {k: v for k, v in config[table].items() if table == "haptic" and k in HAPTIC_SAFETY_KEYS}
            shadows = config.get("shadows")
            shadow = shadows.get(value) if table == "estimator" and isinstance(shadows, dict) else None
            if isinstance(shadow, dict) and shadow.get("name", value) == value:
                kept = {**shadow, "name": value}
                assert isinstance(shadows, dict)  # the shadow came from it
                del shadows[value]
                if not shadows:
                    del config["shadows"]
            config[table] = kept
    for key, value in settings.items():
        key = key.strip()
        if not key:
            raise ConfigError("settings: an empty key; give dotted keys such as session.duration")
        parts = key.split(".")
        if len(parts) > MAX_NESTING:
            raise ConfigError(f"{key[:40]}...: a key of {len(parts)} parts (at most {MAX_NESTING})")
        if parts[0] not in TABLES and parts[0] not in config:
            known = (*TABLES, *_context_tables())
            if parts[0] not in known:
                raise ConfigError(f"{key}: unknown table {parts[0]!r}; tables: {', '.join(known)}")
        node = config
        for depth, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{key}: {'.'.join(parts[: depth + 1])} is not a table")
            node = child
        node[parts[-1]] = value
    return config


def _context_tables() -> list[str]:
    """The config tables the installed plugins' contexts read (e.g. ``world``)."""
    from hapticlab.core.host.registry import Registry

    return Registry().names("context")


def check_tables(config: dict[str, Any], extra_tables: list[str] | tuple[str, ...] = ()) -> None:
    """Refuse unknown top-level tables and plugin tables without a name.

    ``extra_tables`` are the tables of the registered contexts (e.g. ``world``).
    """
    known = (*TABLES, *extra_tables)
    for key, value in config.items():
        if key not in known:
            raise ConfigError(f"{key}: unknown table; tables: {', '.join(known)}")
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: must be a table, got {value!r}")
    for table in PLUGIN_TABLES:
        if table in config and not isinstance(config[table].get("name"), str):
            raise ConfigError(f"{table}.name: missing; name the {table} plugin to use")


def shadow_tables(config: dict[str, Any]) -> dict[str, tuple[str, dict[str, Any]]]:
    """{label: (estimator name, options)} of the ``[shadows.<label>]`` tables."""
    out = {}
    for label, table in config.get("shadows", {}).items():
        if not isinstance(table, dict):
            raise ConfigError(f"shadows.{label}: must be a table ([shadows.{label}]), got {table!r}")
        if not label.isidentifier():
            raise ConfigError(f"shadows.{label}: a label must be a Python identifier (it names the topic)")
        options = dict(table)
        name = options.pop("name", label)
        if not isinstance(name, str):
            raise ConfigError(f"shadows.{label}.name: must be a string, got {name!r}")
        out[label] = (name, options)
    return out


def plugin_options(config: dict[str, Any], table: str) -> tuple[str, dict[str, Any]]:
    """(plugin name, options) of a plugin table, without the host's own keys."""
    section = dict(config.get(table, {}))
    name = section.pop("name", None)
    if table == "haptic":
        section = {k: v for k, v in section.items() if k not in HAPTIC_SAFETY_KEYS}
    return name, section
