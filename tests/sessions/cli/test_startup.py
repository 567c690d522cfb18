"""The command line imports only what the chosen command needs: its parser, ``--version`` and ``plugins``
never import numpy, scipy, matplotlib or numba (the built-in plugins and the commands' work are imported on
use).

Checked in this process, without a fresh interpreter: hapticlab's modules are set aside and imported again
with the heavy libraries made unimportable, so an import of one at start-up fails here, naming who imported it.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator

import pytest

HEAVY = ("numpy", "scipy", "matplotlib", "numba", "llvmlite", "mcap", "dask", "distributed", "pinocchio", "pyarrow")


@pytest.fixture
def light_start() -> Iterator[None]:
    """hapticlab imported afresh, with the HEAVY libraries unimportable; every module restored afterwards."""
    saved = dict(sys.modules)
    for name in list(sys.modules):
        if name == "hapticlab" or name.startswith("hapticlab.") or name.split(".")[0] in HEAVY:
            del sys.modules[name]
    for name in HEAVY:
        sys.modules[name] = None  # type: ignore[assignment]  # `import scipy` now raises ImportError
    try:
        yield
    finally:
        sys.modules.clear()
        sys.modules.update(saved)


def test_version_imports_no_heavy_library(light_start, capsys):
    from hapticlab.sessions.cli import build_parser

    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.startswith("hapticlab ")


def test_plugins_lists_every_builtin_without_importing_one(light_start, capsys):
    from hapticlab.core.host.builtins import BUILTINS
    from hapticlab.core.host.registry import DEFAULT_PLUGINS
    from hapticlab.sessions.cli import main

    assert main(["plugins"]) == 0
    rows = {tuple(cell.strip() for cell in line.split("│")[1:3]) for line in capsys.readouterr().out.splitlines()}
    assert set(BUILTINS.values()) <= rows
    assert not [module for module in DEFAULT_PLUGINS if module in sys.modules]


@pytest.mark.parametrize(
    "command", ["run", "compensate", "replay", "recover", "review", "bench", "discrepancy", "tool"]
)
def test_each_commands_help_builds_without_a_heavy_library(light_start, capsys, command):
    from hapticlab.sessions.cli import build_parser

    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args([command, "--help"])
    assert exit_.value.code == 0 and f"usage: hapticlab {command}" in capsys.readouterr().out


def test_emulate_lists_every_emulator_once_asked(capsys):
    """``emulate``'s subcommands are made on first use (an emulator's module is heavy): its help lists them all."""
    from hapticlab.core.host.registry import Registry
    from hapticlab.sessions.cli import build_parser

    with pytest.raises(SystemExit) as exit_:
        build_parser(load_plugins=False).parse_args(["emulate", "--help"])
    listed = capsys.readouterr().out
    assert exit_.value.code == 0
    assert all(f"    {name} " in listed for name in Registry().names("emulator"))
