"""``hapticlab tool``: the library of known tools (``sessions/tools``): list them, show one, forget one."""

from __future__ import annotations

import argparse

from hapticlab.core.errors import UserError
from hapticlab.sessions.cli.render import vec, wide_console
from hapticlab.sessions.tools import ToolLibrary
from hapticlab.sessions.tools.library import check_name, dumps


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``tool list|show|forget`` to the ``hapticlab`` parser."""
    p = sub.add_parser(
        "tool",
        help="the tool library: each tool's identified mass, centre of gravity, sensor bias and estimator state, "
        "which a session naming the tool ([tool] name) starts from and writes back",
    )
    p.add_argument(
        "--library", default=None, metavar="DIR", help="the library's folder (default: ~/.config/hapticlab/tools)"
    )
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    actions.add_parser("list", help="every tool in the library, a line each").set_defaults(func=tool_list)
    show = actions.add_parser("show", help="one tool's record")
    show.add_argument("name")
    show.set_defaults(func=tool_show)
    forget = actions.add_parser("forget", help="remove a tool's record and its estimator state from the library")
    forget.add_argument("name")
    forget.set_defaults(func=tool_forget)


def tool_list(args: argparse.Namespace) -> int:
    from rich.table import Table

    library = ToolLibrary(args.library)
    names = library.names()
    console = wide_console()
    if not names:
        console.print(f"no tools in {library.folder} (a session with [tool] name = ... adds one)")
        return 0
    table = Table(title=f"tools in {library.folder}")
    for column in ("tool", "mass (kg)", "centre of gravity in S (mm)", "estimator", "state", "sessions", "updated"):
        table.add_column(column, justify="right" if column in ("mass (kg)", "sessions") else "left")
    for name in names:
        record = library.get(name)
        assert record is not None  # (listed: its file exists)
        cog = vec([v * 1e3 for v in record.cog_S], 1)
        state = "warm start" if library.state(name) else "-"
        table.add_row(name, f"{record.mass_kg:.3f}", cog, record.estimator, state, str(record.sessions), record.updated)
    console.print(table)
    return 0


def tool_show(args: argparse.Namespace) -> int:
    library = ToolLibrary(args.library)
    record = library.get(check_name(args.name, "name"))
    if record is None:
        raise UserError(f"{args.name}: no such tool in {library.folder} (hapticlab tool list)")
    print(f"# {library.record_path(args.name)}")
    print(dumps(record), end="")
    state = library.state(args.name)
    print(f"# estimator state: {state}" if state else "# no estimator state (a session starts cold)")
    return 0


def tool_forget(args: argparse.Namespace) -> int:
    library = ToolLibrary(args.library)
    removed = library.forget(check_name(args.name, "name"))
    if not removed:
        raise UserError(f"{args.name}: no such tool in {library.folder} (hapticlab tool list)")
    for path in removed:
        print(f"removed {path}")
    return 0
