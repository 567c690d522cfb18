"""docs/sessions.md lists every session setting the code accepts, and its generated tables are current
(datasette's meta-test: a setting missing from the docs fails here)."""

from __future__ import annotations

import dataclasses
import re

import pytest
from helpers import ROOT

from hapticlab.core.host.registry import Registry
from hapticlab.plugins.simworld import config as world
from hapticlab.plugins.simworld.faults import KINDS as FAULT_KINDS
from hapticlab.sessions import settings_doc
from hapticlab.sessions.config import TABLES
from hapticlab.sessions.settings import HapticSettings, SessionSettings, TeleopSettings
from hapticlab.sessions.tasks.settings import TaskSettings
from hapticlab.sessions.tools.settings import ToolSettings

PAGE = ROOT / "docs" / "sessions.md"


@pytest.fixture(scope="module")
def page() -> str:
    return PAGE.read_text(encoding="utf-8")


def documented(page: str) -> dict[str, set[str]]:
    """block id -> the keys of its table's rows (the first column)."""
    return {ident: set(re.findall(r"^\| `([^`]+)` \|", body, re.M)) for ident, body in settings_doc.block_ids(page)}


def accepted() -> dict[str, set[str]]:
    """block id -> the keys the code accepts there (read from the code, not from the generator)."""
    out = {
        "session": {f.name for f in dataclasses.fields(SessionSettings)},
        "haptic": {f.name for f in dataclasses.fields(HapticSettings)},
        "teleop": {f.name for f in dataclasses.fields(TeleopSettings)},
        "task": {f.name for f in dataclasses.fields(TaskSettings)},
        "tool": {f.name for f in dataclasses.fields(ToolSettings)},
        "world": set(world.WORLD_OPTIONS),
        "world.tool": set(world.TOOL_OPTIONS),
        "world.sensor": set(world.SENSOR_OPTIONS),
        "world.robot": set(world.ROBOT_OPTIONS),
        "world.faults": set(world.FAULT_OPTIONS),
    }
    first_of: dict[type, str] = {}
    for script, checks in world.MOTION_OPTIONS.items():
        name = first_of.setdefault(world.MOTION_SCRIPTS[script], script)  # an alias shares the first's table
        out.setdefault(f"world.motion.{name}", set()).update(checks)
    for kind, checks in world.CONTACT_OPTIONS.items():
        out[f"world.contacts.{kind}"] = set(checks)
    return out


def test_the_generated_tables_are_current(page):
    assert settings_doc.render(page) == page, "run: python -m hapticlab.sessions.settings_doc"


def test_every_setting_the_code_accepts_is_documented(page):
    tables = documented(page)
    code = accepted()
    missing = {ident: sorted(keys - tables.get(ident, set())) for ident, keys in code.items()}
    missing = {ident: keys for ident, keys in missing.items() if keys}
    assert not missing, f"settings missing from {PAGE}: {missing}"
    unknown = {ident: sorted(keys - code.get(ident, set())) for ident, keys in tables.items() if ident != "plugins"}
    unknown = {ident: keys for ident, keys in unknown.items() if keys}
    assert not unknown, f"documented in {PAGE} but not accepted: {unknown}"


def test_every_table_script_and_kind_is_named(page):
    for table in TABLES:
        assert f"`[{table}" in page, table
    for context in Registry().names("context"):
        assert f"## `[{context}]`" in page, context
    for name in [*world.MOTION_SCRIPTS, *world.CONTACT_KINDS, *FAULT_KINDS]:
        assert re.search(rf'`"?{name}"?`', page), name


def test_every_builtin_plugin_says_where_its_options_are_documented(page):
    registry = Registry()
    plugins = next(body for ident, body in settings_doc.block_ids(page) if ident == "plugins")
    for kind in settings_doc.PLUGIN_KINDS:
        for name in settings_doc.builtin_plugins(registry, kind):
            assert (kind, name) in settings_doc.PLUGIN_DOCS, f"{kind} {name}: add it to PLUGIN_DOCS"
            assert f"| `{name}` |" in plugins, name


def test_every_setting_has_a_meaning_and_a_default_or_says_it_is_required():
    for ident, rows in settings_doc.tables().items():
        for key, what, _default, meaning in rows:
            assert meaning and what, (ident, key)


def test_docstring_entries_are_read_in_both_styles():
    class Base:
        """A base.

        Parameters
        ----------
        a : the first, m.
        b, c : two at once,
            over two lines.
        """

    class Child(Base):
        """A child.

        Attributes:
            a: as Base.
            d: the fourth
                (continued).
        """

    assert settings_doc.field_docs(Child) == {
        "a": "the first, m.",
        "b": "two at once, over two lines.",
        "c": "two at once, over two lines.",
        "d": "the fourth (continued).",
    }
