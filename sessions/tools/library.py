"""The tool library: each tool's identified weight, centre of gravity and sensor bias, kept between sessions.

One TOML file per tool, ``<name>.toml`` (:class:`ToolRecord`), and the primary estimator's warm-start state
beside it, ``<name>.state.json`` (the same JSON a session writes as ``<recording>.calibration.json``), in a
folder: ``[tool] library``, else ``$XDG_CONFIG_HOME/hapticlab/tools`` (``~/.config/hapticlab/tools``). A
session that names its tool starts from it (``prepare``) and writes it back when it ends with the tool
identified; the recordings keep every session's own state, so the library holds only the latest.
"""

from __future__ import annotations

import json
import math
import os
import re
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hapticlab.core.errors import ConfigError, UserError

STANDARD_GRAVITY = 9.80665
"""m/s²: the weight identified, as a mass (local gravity differs by under 0.3 %)."""
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
"""A tool's name: a file name on every system (no path, no leading dot), up to 64 characters."""
MAX_RECORD_BYTES = 64 << 10
"""A tool's TOML file is read up to this size, bytes (a record is a few hundred)."""
MAX_STATE_BYTES = 16 << 20
"""...and its state up to this (``kalman``'s warm-start bound)."""


def check_name(name: str, where: str = "tool.name") -> str:
    """``name`` when it is a tool's name (``NAME``), else ConfigError saying what one is."""
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise ConfigError(
            f"{where}: {name!r} is not a tool name: letters, digits, '_', '.', '-', up to 64, not starting with "
            "'.' or '-' (it names a file in the tool library)"
        )
    return name


def default_folder() -> Path:
    """``$XDG_CONFIG_HOME/hapticlab/tools``, or ``~/.config/hapticlab/tools``."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "hapticlab" / "tools"


@dataclass(frozen=True)
class ToolRecord:
    """What the library knows of one tool, as the last session that identified it left it.

    Attributes:
        name: the tool's name (its file's).
        mass_kg: the identified weight as a mass, kg (the tool and adapter below the sensing plane).
        cog_S: its centre of gravity in the sensor frame S, m.
        bias_force_S, bias_torque_S: the sensor's bias at that session's end, N and N·m (a bias drifts:
            a start from it is a start, not the truth).
        estimator: the estimator that identified it; its state is what a warm start loads.
        updated: when, UTC (ISO 8601).
        sessions: how many sessions have written it.
        recording: the last recording that did.
    """

    name: str
    mass_kg: float
    cog_S: tuple[float, float, float]
    bias_force_S: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bias_torque_S: tuple[float, float, float] = (0.0, 0.0, 0.0)
    estimator: str = ""
    updated: str = ""
    sessions: int = 0
    recording: str = ""

    @staticmethod
    def from_params(name: str, params: dict[str, list[float]], **info: Any) -> ToolRecord | None:
        """The record an estimator's ``params`` give (None without a weight and a centre of gravity)."""
        g, cog = params.get("gravity_force_B"), params.get("cog_S")
        if g is None or cog is None or not all(map(math.isfinite, [*g, *cog])):
            return None
        mass = math.sqrt(sum(v * v for v in g)) / STANDARD_GRAVITY
        zero = (0.0, 0.0, 0.0)
        bias_force_S, bias_torque_S = (_vec(params.get(key, zero)) for key in ("bias_force_S", "bias_torque_S"))
        return ToolRecord(name, mass, _vec(cog), bias_force_S, bias_torque_S, **info)


class ToolLibrary:
    """The tools in ``folder`` (module docstring); the folder is made when a tool is first saved."""

    def __init__(self, folder: str | Path | None = None):
        self.folder = Path(folder).expanduser() if folder else default_folder()

    def record_path(self, name: str) -> Path:
        return self.folder / f"{check_name(name)}.toml"

    def state_path(self, name: str) -> Path:
        return self.folder / f"{check_name(name)}.state.json"

    def names(self) -> list[str]:
        """The tools the library holds, sorted."""
        if not self.folder.is_dir():
            return []
        return sorted(p.stem for p in self.folder.glob("*.toml") if NAME.fullmatch(p.stem) and p.is_file())

    def get(self, name: str) -> ToolRecord | None:
        """The tool's record, None when the library does not hold it; UserError naming the file when it is
        not a record (not a regular file, too large, not TOML, a key missing or of the wrong kind)."""
        path = self.record_path(name)
        if not path.exists():
            return None
        try:
            table = tomllib.loads(_read(path, MAX_RECORD_BYTES))
        except tomllib.TOMLDecodeError as exc:
            raise UserError(f"{path}: not a tool record (invalid TOML: {exc})") from None
        try:
            record = ToolRecord(
                name,
                float(table["mass_kg"]),
                _vec(table["cog_S"]),
                _vec(table.get("bias_force_S", (0, 0, 0))),
                _vec(table.get("bias_torque_S", (0, 0, 0))),
                str(table.get("estimator", "")),
                str(table.get("updated", "")),
                int(table.get("sessions", 0)),
                str(table.get("recording", "")),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise UserError(f"{path}: not a tool record ({type(exc).__name__}: {exc}); forget it or fix it") from None
        if record.sessions < 0 or not all(
            map(math.isfinite, (*record.cog_S, *record.bias_force_S, *record.bias_torque_S))
        ):
            raise UserError(f"{path}: not a tool record (a negative session count or a non-finite vector)")
        if not (math.isfinite(record.mass_kg) and record.mass_kg > 0):
            raise UserError(f"{path}: mass_kg must be a positive number of kg, got {record.mass_kg!r}")
        return record

    def state(self, name: str) -> Path | None:
        """The tool's saved estimator state, when there is one."""
        path = self.state_path(name)
        return path if path.is_file() else None

    def read_state(self, name: str) -> dict[str, Any] | None:
        """The tool's saved estimator state as JSON (None: none saved); UserError naming the file when it is not."""
        path = self.state(name)
        if path is None:
            return None
        try:
            state = json.loads(_read(path, MAX_STATE_BYTES))
        except (json.JSONDecodeError, RecursionError) as exc:
            raise UserError(f"{path}: not an estimator state ({type(exc).__name__})") from None
        if not isinstance(state, dict):
            raise UserError(f"{path}: not an estimator state (a JSON object is)")
        return state

    def save(self, record: ToolRecord, state: dict[str, Any] | None) -> Path:
        """Write ``record`` (and ``state``, or remove a stale one) atomically: a reader never sees half a file."""
        self.folder.mkdir(parents=True, exist_ok=True)
        if state is not None:
            _replace(self.state_path(record.name), json.dumps(state, indent=1))
        elif (old := self.state(record.name)) is not None:
            old.unlink()
        _replace(self.record_path(record.name), dumps(record))
        return self.record_path(record.name)

    def forget(self, name: str) -> list[Path]:
        """Remove the tool's record and state: the paths removed (none when the library did not hold it)."""
        removed = []
        for path in (self.record_path(name), self.state_path(name)):
            if path.is_file():
                path.unlink()
                removed.append(path)
        return removed


def dumps(record: ToolRecord) -> str:
    """The record as TOML (flat: numbers, strings, arrays of numbers)."""
    lines = [f"# hapticlab tool record: {record.name}"]
    for key, value in asdict(record).items():
        if key == "name":
            continue
        if isinstance(value, str):
            lines.append(f"{key} = {json.dumps(value)}")
        elif isinstance(value, (tuple, list)):
            lines.append(f"{key} = [{', '.join(repr(float(v)) for v in value)}]")
        else:
            lines.append(f"{key} = {value!r}")
    return "\n".join(lines) + "\n"


def _vec(value: Any) -> tuple[float, float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ValueError(f"expected three numbers, got {value!r}")
    x, y, z = (float(v) for v in value)
    return (x, y, z)


def _read(path: Path, limit: int) -> str:
    """A regular file's UTF-8 text, at most ``limit`` bytes; UserError naming the file otherwise."""
    if not path.is_file():
        raise UserError(f"{path}: not a regular file")
    with path.open("rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise UserError(f"{path}: larger than {limit >> 10} KiB: not a tool record or state")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not UTF-8 text (byte {exc.start}): not a tool record") from None


def _replace(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it and a rename (atomic on POSIX)."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)
