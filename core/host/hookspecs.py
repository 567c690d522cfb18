"""Hook specifications: how a plugin tells hapticlab what it provides.

Every hook is called once, at start-up, with a ``register(name, factory)``
callback; the plugin calls it for each thing it provides and returns nothing.
The host then builds plain objects from the factories and calls those in the
per-sample loop (a hook call costs microseconds; none happen per sample).
Full prose for each hook is in ``docs/plugins.md``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("hapticlab")
hookimpl = pluggy.HookimplMarker("hapticlab")

Register = Callable[[str, Callable[..., Any]], None]


@hookspec
def register_sensors(register: Register) -> None:
    """Register force/torque sensor sources: register(name, factory)."""


@hookspec
def register_kinematics(register: Register) -> None:
    """Register robot kinematics sources (orientation of E in B): register(name, factory)."""


@hookspec
def register_estimators(register: Register) -> None:
    """Register non-contact wrench estimators: register(name, factory)."""


@hookspec
def register_haptic_outputs(register: Register) -> None:
    """Register haptic master-device outputs: register(name, factory)."""


@hookspec
def register_effects(register: Register) -> None:
    """Register physical effect models for the discrepancy workflow: register(name, factory).

    An effect's ``apply`` runs in several threads at once: it must not change the effect (``Effect.apply``)."""


@hookspec
def register_contexts(register: Register) -> None:
    """Register shared objects built from a config table of the same name: register(table, factory(table))."""


@hookspec
def register_emulators(register: Register) -> None:
    """Register device emulators for ``hapticlab emulate NAME``: register(name, EmulatorCommand(...))."""


@hookspec
def register_commands(cli: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add subcommands to the ``hapticlab`` command line: cli.add_parser(...), set_defaults(func=...)."""


KINDS: dict[str, str] = {
    "sensor": "register_sensors",
    "kinematics": "register_kinematics",
    "estimator": "register_estimators",
    "haptic_output": "register_haptic_outputs",
    "effect": "register_effects",
    "context": "register_contexts",
    "emulator": "register_emulators",
}
"""Kind of plugin -> the hook that registers it."""
