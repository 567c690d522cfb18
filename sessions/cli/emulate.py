"""``hapticlab emulate``: a real device's wire protocol on an address of this machine, fed by the simulated world.

Each emulator lives beside its plugin (``plugins/<kind>/<device>_emulator.py``;
``lab``, a Net F/T and a UR arm on one world, in ``plugins/lab_emulator.py``)
and registers an ``EmulatorCommand`` through the ``register_emulators`` hook,
so a third party adds one as it adds a sensor; this module makes a subcommand
of each. An emulator fed by a simulated world (``needs_world``) gets
``--session`` and ``--seed`` here: this host loads the session and builds its
world through the registry's ``world`` context, as a session does, and hands
it to the emulator's ``run(args, world)``. An emulator prints where it listens
on its first line, then serves until Ctrl-C, SIGTERM or ``--duration``; the
vendor's own client (``pynetft``, ``ur-rtde``) connects to it as to the device.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any, cast

import pluggy

from hapticlab.core.host.options import OptionError, listen_address
from hapticlab.core.host.registry import Registry
from hapticlab.sessions.config import load_config

if TYPE_CHECKING:  # core.types imports numpy, which building the parser does not need
    from hapticlab.core.types import EmulatorCommand


class _Devices(argparse._SubParsersAction):
    """``emulate``'s DEVICE subcommands, made the first time they are needed (parsing ``emulate ...`` or its
    help): an emulator's options are in its module, whose import (the simulated world, numpy, the wire
    codecs) no other command should pay for."""

    def __init__(self, *args: Any, fill: Callable[[argparse._SubParsersAction], None], **kwargs: Any) -> None:
        self._fill: Callable[[argparse._SubParsersAction], None] | None = fill
        super().__init__(*args, **kwargs)

    def _filled(self) -> None:
        if self._fill is not None:
            fill, self._fill = self._fill, None
            fill(self)

    @property
    def choices(self) -> Any:  # argparse checks a device name against these
        self._filled()
        return self._name_parser_map

    @choices.setter
    def choices(self, value: Any) -> None:  # set by argparse.Action.__init__ (the same mapping)
        pass

    def _get_subactions(self) -> list[argparse.Action]:  # what ``emulate --help`` lists
        self._filled()
        return super()._get_subactions()

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        self._filled()
        super().__call__(parser, namespace, values, option_string)


def add_commands(sub: argparse._SubParsersAction, pm: pluggy.PluginManager) -> None:
    """``emulate`` and one subcommand per registered emulator (``register_emulators``), made on first use."""
    parser = sub.add_parser(
        "emulate",
        help="serve a real device's protocol on this machine (a loopback address by default), fed by the simulator",
        description=__doc__.split("\n\n")[0],
    )
    parser.add_subparsers(
        dest="device", required=True, metavar="DEVICE", action=_Devices, fill=partial(add_devices, Registry(pm))
    )


def add_devices(registry: Registry, devices: argparse._SubParsersAction) -> None:
    """One subcommand of ``emulate`` per emulator the registry holds, with its options."""
    for name in registry.names("emulator"):
        # register_emulators registers EmulatorCommand objects (docs/plugins.md); the registry types every
        # factory as a callable
        emulator = cast("EmulatorCommand", registry.get("emulator", name).factory)
        # a registered name is an identifier; the command line also takes it with hyphens (robotiq-ft300)
        aliases = [name.replace("_", "-")] if "_" in name else []
        device = devices.add_parser(name, aliases=aliases, help=emulator.help, description=emulator.help)
        emulator.add_arguments(device)
        if getattr(emulator, "needs_world", False):
            device.add_argument(
                "--session",
                default=emulator.session,
                help=f"preset name or TOML file whose [world] feeds the emulator (default: {emulator.session})",
            )
            device.add_argument("--seed", type=int, default=None, help="the world's seed (overrides the session's)")
        if getattr(emulator, "listens_on", ()):
            device.add_argument(
                "--allow-network",
                action="store_true",
                help="allow a non-loopback address above: anyone on the network can then connect to the emulated "
                "device (it has no authentication)",
            )
        device.set_defaults(func=partial(run_emulator, registry, emulator))


def run_emulator(registry: Registry, emulator: EmulatorCommand, args: argparse.Namespace) -> int:
    """Run one emulator: with ``needs_world``, on the world of ``args.session`` (``args.seed`` overriding its seed).
    The addresses it listens on (``listens_on``) are loopback ones unless ``--allow-network`` (ConfigError)."""
    for dest in getattr(emulator, "listens_on", ()):
        try:
            listen_address(
                f"--{dest.replace('_', '-')}",
                getattr(args, dest),
                allow_network=args.allow_network,
                exposes=f"the emulated device ({args.device})",
            )
        except OptionError as exc:
            raise exc.under("") from None
    if not getattr(emulator, "needs_world", False):
        return emulator.run(args)
    return emulator.run(args, simulated_world(registry, args.session, args.seed))


def simulated_world(registry: Registry, session: str, seed: int | None = None) -> Any:
    """The simulated world of a session's ``[world]`` table, built by the registry's ``world`` context.

    ConfigError naming the session (no such preset or file) or the key (``world.tool.mass: ...``).
    """
    config, _ = load_config(session)
    table = dict(config.get("world") or {})
    if seed is not None:
        table["seed"] = seed
    return registry.create("context", "world", {"table": table}, where="world")
