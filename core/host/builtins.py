"""The built-in plugins, indexed by what each registers, so finding them imports none of them.

Each built-in is a module with its own hooks, written as a third party writes one
(``@hookimpl def register_sensors(register): register("sim", SimSensor)``). Importing
them all costs seconds (numba kernels, scipy), which every command, ``hapticlab --version``
included, would pay at start-up. So the plugin manager holds, under each module's name,
a :class:`BuiltinPlugin`: a stand-in whose hook registers the indexed name with a
:class:`Deferred` factory. The module is imported, and its own hook run, the first
time that factory is needed (``Registry.get(...).factory``, ``Registry.create``).
Tests check the index against the modules' own hooks and against the modules under
``plugins/`` that have one, so a new built-in missing here (or a renamed one) fails there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from hapticlab.core.errors import PluginError
from hapticlab.core.host.hookspecs import KINDS, hookimpl

BUILTINS: dict[str, tuple[str, str]] = {
    "hapticlab.plugins.sensors.sim": ("sensor", "sim"),
    "hapticlab.plugins.sensors.netft": ("sensor", "netft"),
    "hapticlab.plugins.sensors.bota": ("sensor", "bota"),
    "hapticlab.plugins.sensors.robotiq_ft300": ("sensor", "robotiq_ft300"),
    "hapticlab.plugins.kinematics.sim": ("kinematics", "sim"),
    "hapticlab.plugins.kinematics.ur_rtde": ("kinematics", "ur_rtde"),
    "hapticlab.plugins.kinematics.urdf": ("kinematics", "urdf"),
    "hapticlab.plugins.estimators.rls": ("estimator", "rls"),
    "hapticlab.plugins.estimators.batch": ("estimator", "batch"),
    "hapticlab.plugins.estimators.kalman": ("estimator", "kalman"),
    "hapticlab.plugins.haptics.null": ("haptic_output", "null"),
    "hapticlab.plugins.haptics.sim_master": ("haptic_output", "sim"),
    "hapticlab.plugins.haptics.serial": ("haptic_output", "serial"),
    "hapticlab.plugins.haptics.hid": ("haptic_output", "hid"),
    "hapticlab.plugins.sensors.netft_emulator": ("emulator", "netft"),
    "hapticlab.plugins.kinematics.ur_emulator": ("emulator", "ur"),
    "hapticlab.plugins.haptics.master_emulator_cli": ("emulator", "master"),
    "hapticlab.plugins.sensors.bota_emulator_cli": ("emulator", "bota"),
    "hapticlab.plugins.sensors.robotiq_emulator_cli": ("emulator", "robotiq_ft300"),
    "hapticlab.plugins.lab_emulator": ("emulator", "lab"),
    "hapticlab.plugins.simworld.context": ("context", "world"),
    "hapticlab.plugins.effects.mount_rotation": ("effect", "mount_rotation"),
    "hapticlab.plugins.effects.bias_drift": ("effect", "bias_drift"),
    "hapticlab.plugins.effects.warm_up": ("effect", "warm_up"),
    "hapticlab.plugins.effects.inertia": ("effect", "inertia"),
    "hapticlab.plugins.effects.payload_change": ("effect", "payload_change"),
    "hapticlab.plugins.effects.time_lag": ("effect", "time_lag"),
    "hapticlab.plugins.effects.gain_crosstalk": ("effect", "gain_crosstalk"),
    "hapticlab.plugins.effects.hysteresis": ("effect", "hysteresis"),
}
"""Built-in module -> (kind, name) it registers through its own hook (``hookspecs.KINDS``)."""


def registered_by(module: Any, kind: str) -> dict[str, Callable[..., Any]]:
    """What ``module``'s own hook for ``kind`` registers: name -> factory (empty without such a hook)."""
    hook = getattr(module, KINDS[kind], None)
    found: dict[str, Callable[..., Any]] = {}
    if hook is not None:
        hook(register=found.__setitem__)
    return found


class Deferred:
    """The factory a built-in module registers as ``name``, found by importing it on first use.

    Calling it builds as the factory would; :meth:`load` gives the factory itself (what the registry
    inspects for options). A PluginError when the module no longer registers that name (the index above
    is out of step).
    """

    def __init__(self, module: str, kind: str, name: str) -> None:
        self.module, self.kind, self.name = module, kind, name

    def load(self) -> Callable[..., Any]:
        factory = registered_by(importlib.import_module(self.module), self.kind).get(self.name)
        if factory is None:
            raise PluginError(
                f"{self.module}: indexed as registering {self.kind} {self.name!r} (core/host/builtins.py) "
                "but its hook does not"
            )
        if not callable(factory):
            raise PluginError(f"{self.module}: {self.kind} {self.name!r} factory is not callable")
        return factory

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.load()(*args, **kwargs)

    def __repr__(self) -> str:
        return f"Deferred({self.module!r}, {self.kind!r}, {self.name!r})"


class BuiltinPlugin:
    """The stand-in for one built-in module in the plugin manager: its one hook registers a :class:`Deferred`."""

    def __init__(self, module: str) -> None:
        kind, name = BUILTINS[module]
        self.__name__ = module

        @hookimpl
        def hook(register: Callable[[str, Callable[..., Any]], None]) -> None:
            register(name, Deferred(module, kind, name))

        setattr(self, KINDS[kind], hook)

    def __repr__(self) -> str:
        return f"BuiltinPlugin({self.__name__!r})"
