"""The plugin host: hooks, registration, errors, and the meta-tests on hooks and docs."""

from __future__ import annotations

import importlib
import inspect
import types
from pathlib import Path

import pluggy
import pytest
from helpers import ROOT

from hapticlab.core import hookimpl
from hapticlab.core.host import hookspecs
from hapticlab.core.host.builtins import BUILTINS, Deferred, registered_by
from hapticlab.core.host.interfaces import CAPABILITIES
from hapticlab.core.host.registry import DEFAULT_PLUGINS, KINDS, ConfigError, PluginError, Registry, make_plugin_manager
from hapticlab.sessions.live.build import REQUIRED

DOCS = ROOT / "docs" / "plugins.md"
HOOKS = sorted(n for n, f in vars(hookspecs).items() if n.startswith("register_") and callable(f))


def manager_with(*modules) -> pluggy.PluginManager:
    pm = pluggy.PluginManager("hapticlab")
    pm.add_hookspecs(hookspecs)
    for module in modules:
        pm.register(module, name=module.__name__)
    return pm


def plugin_module(name: str, **hooks) -> types.ModuleType:
    module = types.ModuleType(name)
    for hook_name, function in hooks.items():
        setattr(module, hook_name, hookimpl(function))
    return module


class Dummy:
    def __init__(self, gain: float = 1.0, label: str = "x", enabled: bool = True, axes: list[float] | None = None):
        self.gain, self.label, self.enabled, self.axes = gain, label, enabled, axes


def test_every_hook_is_exercised_here():
    """datasette-style meta-test: each hookspec is registered through in this file."""
    source = Path(__file__).read_text()
    for hook in HOOKS:
        assert f"{hook}=" in source, f"{hook} is not exercised by a test"
    assert set(HOOKS) == set(KINDS.values()) | {"register_commands"}


def _plain(signature: inspect.Signature) -> str:
    """A signature as the docs write it: parameter names only, no self, no annotations."""
    return "(" + ", ".join(n for n in signature.parameters if n != "self") + ")"


def test_every_hook_is_documented_with_its_signature():
    docs = DOCS.read_text()
    for hook in HOOKS:
        assert f"## {hook}{_plain(inspect.signature(getattr(hookspecs, hook)))}" in docs, hook


def _members(protocol) -> list[str]:
    """Each member of an interface or capability as the docs write it: ``name(args) -> type`` or ``name: type``."""
    out = []
    for name, annotation in getattr(protocol, "__annotations__", {}).items():
        out.append(f"{name}: {annotation}")
    for name, value in vars(protocol).items():
        if callable(value) and not name.startswith("_"):
            sig = inspect.signature(value)
            params = ", ".join(str(p).replace("'", "") for p in sig.parameters.values() if p.name != "self")
            out.append(f"{name}({params}) -> {str(sig.return_annotation).replace(chr(39), '')}")
    return out


@pytest.mark.parametrize("protocol", [*REQUIRED, *CAPABILITIES], ids=lambda p: p.__name__)
def test_every_interface_and_capability_is_documented_with_its_exact_members(protocol):
    docs = DOCS.read_text()
    assert f"### {protocol.__name__}" in docs, protocol.__name__
    section = docs.split(f"### {protocol.__name__}", 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
    for member in _members(protocol):
        assert f"`{member}`" in section, f"{protocol.__name__}: `{member}` is not in docs/plugins.md"


def test_a_plugin_adds_a_subcommand(capsys):
    from hapticlab.sessions.cli import build_parser

    def add(cli):
        p = cli.add_parser("hello", help="say hello")
        p.add_argument("--name", default="lab")
        p.set_defaults(func=lambda args: print(f"hello {args.name}") or 0)

    pm = manager_with(plugin_module("greeter", register_commands=add))
    parser = build_parser(load_plugins=False)
    sub = next(a for a in parser._actions if a.dest == "command")
    pm.hook.register_commands(cli=sub)
    args = parser.parse_args(["hello", "--name", "surgeon"])
    assert args.func(args) == 0 and capsys.readouterr().out == "hello surgeon\n"


@pytest.mark.parametrize("hook", sorted(KINDS.values()))
def test_each_hook_registers_its_kind(hook):
    kind = {v: k for k, v in KINDS.items()}[hook]
    module = plugin_module(f"third_party_{kind}", **{hook: lambda register: register("thing", Dummy)})
    registry = Registry(manager_with(module))
    entry = registry.get(kind, "thing")
    assert entry.factory is Dummy and entry.origin == f"third_party_{kind}"
    assert registry.names(kind) == ["thing"]


def test_every_kind_in_one_plugin():
    module = plugin_module(
        "everything",
        register_sensors=lambda register: register("s", Dummy),
        register_kinematics=lambda register: register("k", Dummy),
        register_estimators=lambda register: register("e", Dummy),
        register_haptic_outputs=lambda register: register("h", Dummy),
        register_effects=lambda register: register("f", Dummy),
        register_contexts=lambda register: register("c", Dummy),
        register_emulators=lambda register: register("m", Dummy),
    )
    registry = Registry(manager_with(module))
    assert [(e.kind, e.name) for e in registry.entries()] == [
        ("sensor", "s"),
        ("kinematics", "k"),
        ("estimator", "e"),
        ("haptic_output", "h"),
        ("effect", "f"),
        ("context", "c"),
        ("emulator", "m"),
    ]


def test_a_third_party_emulator_is_a_subcommand_of_emulate():
    """``hapticlab emulate NAME`` for every registered emulator, its options and its run included."""
    import argparse

    from hapticlab.core.types import EmulatorCommand
    from hapticlab.sessions.cli import emulate

    served = []

    def add_arguments(parser):
        parser.add_argument("--address", default="127.0.0.1")

    def run(args):
        served.append(args.address)
        return 0

    toy = EmulatorCommand(help="a toy gripper on loopback", add_arguments=add_arguments, run=run)
    module = plugin_module("gripper_emulator", register_emulators=lambda register: register("gripper", toy))
    parser = argparse.ArgumentParser(prog="hapticlab")
    emulate.add_commands(parser.add_subparsers(dest="command"), manager_with(module))
    args = parser.parse_args(["emulate", "gripper", "--address", "127.0.0.9"])
    assert args.func(args) == 0 and served == ["127.0.0.9"]
    with pytest.raises(SystemExit):
        parser.parse_args(["emulate", "netft"])  # only what this manager registered


def test_an_emulator_that_needs_a_world_gets_the_sessions_world_from_the_host():
    """``needs_world``: the host adds ``--session`` and ``--seed``, builds the world through the ``world``
    context and passes it to ``run(args, world)``; the emulator reads no session itself."""
    import argparse

    from hapticlab.core.types import EmulatorCommand
    from hapticlab.plugins.simworld import context
    from hapticlab.sessions.cli import emulate

    worlds = []
    toy = EmulatorCommand(
        help="a toy F/T sensor",
        add_arguments=lambda parser: parser.add_argument("--duration", type=float),
        run=lambda args, world: worlds.append(world) or 0,
        needs_world=True,
        session="lab-emulated",
    )
    module = plugin_module("toy_sensor_emulator", register_emulators=lambda register: register("toy", toy))
    parser = argparse.ArgumentParser(prog="hapticlab")
    emulate.add_commands(parser.add_subparsers(dest="command"), manager_with(module, context))
    args = parser.parse_args(["emulate", "toy", "--seed", "12"])
    assert args.session == "lab-emulated" and args.func(args) == 0
    assert worlds[0].seed == 12 and type(worlds[0]).__name__ == "SimWorld"
    args = parser.parse_args(["emulate", "toy", "--session", "demo"])
    assert args.func(args) == 0 and worlds[1].seed == 7  # the demo preset's


def test_builtins_are_registered():
    registry = Registry(make_plugin_manager(load_entry_points=False))
    assert "sim" in registry.names("sensor")
    assert "sim" in registry.names("kinematics")
    assert {"rls", "batch"} <= set(registry.names("estimator"))
    assert "null" in registry.names("haptic_output")
    assert registry.get("estimator", "rls").origin == "hapticlab.plugins.estimators.rls"
    assert len(DEFAULT_PLUGINS) == len(set(DEFAULT_PLUGINS))


@pytest.mark.parametrize("module_name", DEFAULT_PLUGINS)
def test_the_builtin_index_is_what_each_module_registers(module_name):
    """The index the host lists built-ins from (without importing them) matches each module's own hooks; the
    registry's factory, imported on first use, is the one the module registers."""
    module = importlib.import_module(module_name)
    registered = {kind: registered_by(module, kind) for kind in KINDS}
    kind, name = BUILTINS[module_name]
    assert {k: list(found) for k, found in registered.items() if found} == {kind: [name]}
    entry = Registry(make_plugin_manager(load_entry_points=False)).get(kind, name)
    assert entry.factory == registered[kind][name] and entry.origin == module_name


def test_every_module_of_the_plugins_folder_with_a_hook_is_indexed():
    """A new built-in (a module under plugins/ with an @hookimpl) is in the index, or nothing would register it."""
    hooked = set()
    for path in (ROOT / "plugins").rglob("*.py"):
        if "@hookimpl" in path.read_text(encoding="utf-8"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            hooked.add(".".join(("hapticlab", *(parts[:-1] if parts[-1] == "__init__" else parts))))
    assert hooked == set(BUILTINS)


def test_an_index_out_of_step_with_its_module_names_both():
    with pytest.raises(PluginError, match=r"hapticlab.plugins.effects.inertia: indexed as registering effect 'lag'"):
        Deferred("hapticlab.plugins.effects.inertia", "effect", "lag").load()


def test_duplicate_name_is_an_error_naming_both_plugins():
    a = plugin_module("plugin_a", register_estimators=lambda register: register("same", Dummy))
    b = plugin_module("plugin_b", register_estimators=lambda register: register("same", Dummy))
    with pytest.raises(PluginError, match=r"estimator 'same' registered twice: by plugin_. and by plugin_."):
        Registry(manager_with(a, b))


def test_unknown_name_lists_the_available_ones():
    module = plugin_module("p", register_estimators=lambda register: register("rls", Dummy))
    registry = Registry(manager_with(module))
    with pytest.raises(PluginError, match=r"unknown estimator 'rsl'; available: rls"):
        registry.get("estimator", "rsl")


def test_bad_names_and_factories_are_refused():
    bad_name = plugin_module("p1", register_sensors=lambda register: register("not a name", Dummy))
    with pytest.raises(PluginError, match="p1: sensor name 'not a name' is not a valid identifier"):
        Registry(manager_with(bad_name))
    bad_factory = plugin_module("p2", register_sensors=lambda register: register("ok", 42))
    with pytest.raises(PluginError, match="not callable"):
        Registry(manager_with(bad_factory))


def test_typo_in_a_hook_name_is_caught():
    module = types.ModuleType("typo")
    module.register_estimator = hookimpl(lambda register: None)  # missing "s"
    pm = manager_with(module)
    with pytest.raises(pluggy.PluginValidationError):
        pm.check_pending()


def test_create_checks_options_against_the_signature():
    module = plugin_module("p", register_estimators=lambda register: register("d", Dummy))
    registry = Registry(manager_with(module))
    made = registry.create("estimator", "d", {"gain": 2, "axes": [1, 2.5]}, where="estimator")
    assert made.gain == 2.0 and isinstance(made.gain, float) and made.axes == [1, 2.5]
    with pytest.raises(
        ConfigError,
        match=r"^estimator.gian: unknown option; did you mean gain\?; known options: axes, enabled, gain, label$",
    ):
        registry.create("estimator", "d", {"gian": 2}, where="estimator")
    with pytest.raises(ConfigError, match=r"^estimator.gain: must be a number, got 'high'$"):
        registry.create("estimator", "d", {"gain": "high"}, where="estimator")
    with pytest.raises(ConfigError, match=r"^estimator.enabled: must be true or false, got 1$"):
        registry.create("estimator", "d", {"enabled": 1}, where="estimator")
    with pytest.raises(ConfigError, match=r"^estimator.axes: must be a list of numbers, got \['a'\]$"):
        registry.create("estimator", "d", {"axes": ["a"]}, where="estimator")


def test_host_context_is_passed_only_to_factories_that_take_it():
    class WithWorld:
        def __init__(self, rate_hz: float = 1.0, world=None):
            self.world = world

    module = plugin_module(
        "p",
        register_sensors=lambda register: register("w", WithWorld),
        register_kinematics=lambda register: register("d", Dummy),
        register_contexts=lambda register: register("world", lambda table: table),
    )
    registry = Registry(manager_with(module))
    assert registry.create("sensor", "w", {}, world="W").world == "W"
    assert registry.create("kinematics", "d", {}, world="W").gain == 1.0
    with pytest.raises(ConfigError, match=r"sensor.world: unknown option"):
        registry.create("sensor", "w", {"world": "user-supplied"}, where="sensor")


def test_load_plugins_switch_limits_entry_points(monkeypatch):
    monkeypatch.setenv("HAPTICLAB_LOAD_PLUGINS", "")
    pm = make_plugin_manager()
    assert sorted(pm.get_name(p) for p in pm.get_plugins()) == sorted(DEFAULT_PLUGINS)
