"""The ``hapticlab`` command line: a thin shell over the Python API.

One module per command group (``run``, ``offline``, ``bench``, ``discrepancy``, ``review``, ``emulate``),
each with an ``add_commands(sub)``; plugins add theirs through the
``register_commands`` hook. The error policy (``errors``): a user's mistake is
one line naming the problem and exit status 2; a bug keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys

from hapticlab.core.host.registry import make_plugin_manager
from hapticlab.core.version import __version__
from hapticlab.sessions.cli import bench, discrepancy, emulate, offline, review, run, tool
from hapticlab.sessions.cli.errors import is_user_error, one_line
from hapticlab.sessions.cli.render import err

COMMAND_MODULES = (run, offline, bench, discrepancy, review, tool)


def build_parser(load_plugins: bool = True) -> argparse.ArgumentParser:
    """The parser with every built-in subcommand, and those plugins add (``register_commands``)."""
    parser = argparse.ArgumentParser(
        prog="hapticlab",
        description="Haptic teleoperation for robotic-surgery training: real-time F/T compensation, recorded sessions.",
    )
    parser.add_argument("--version", action="version", version=f"hapticlab {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMAND_MODULES:
        module.add_commands(sub)
    pm = make_plugin_manager(load_entry_points=load_plugins)
    emulate.add_commands(sub, pm)  # one subcommand per registered emulator
    if load_plugins:
        pm.hook.register_commands(cli=sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        err.print("interrupted")
        return 130
    except Exception as exc:
        if not is_user_error(exc):
            raise  # a bug in hapticlab (or a plugin) keeps its traceback
        print(f"hapticlab {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
