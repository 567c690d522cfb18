"""``hapticlab run`` and ``hapticlab plugins``: a live session with its status line, the plugin list."""

from __future__ import annotations

import argparse
import sys

from rich.console import Console
from rich.live import Live
from rich.table import Table

from ...core.plugins import KINDS, Registry
from .render import err

out = Console()


def cmd_plugins(args: argparse.Namespace) -> int:
    registry = Registry()
    table = Table(title="hapticlab plugins")
    table.add_column("kind")
    table.add_column("name", style="bold")
    table.add_column("from")
    for entry in registry.entries():
        table.add_row(entry.kind, entry.name, entry.origin)
    out.print(table)
    empty = [k for k in KINDS if not registry.names(k)]
    if empty:
        out.print(f"no plugins yet for: {', '.join(empty)}")
    return 0


def _status_table(status) -> Table:
    table = Table.grid(padding=(0, 2))
    haptic = "[green]on[/]" if status.haptic_enabled else f"[yellow]off[/] ({status.reason})"
    table.add_row(
        f"t {status.elapsed_s:6.1f} s",
        f"{status.samples} samples @ {status.rate_hz:6.0f} Hz",
        "force " + ("[green]converged[/]" if status.converged_force else "[yellow]converging[/]"),
        "torque " + ("[green]converged[/]" if status.converged_torque else "[yellow]converging[/]"),
        "[red]CONTACT[/]" if status.contact else "free",
        f"haptic {haptic}",
        f"{status.events} events",
        *([f"[red]{status.behind_s * 1e3:.0f} ms behind[/]"] if status.behind_s > 0 else []),
    )
    return table


def cmd_run(args: argparse.Namespace) -> int:
    from ..config import apply_overrides, check_duration, load_config
    from ..live import SessionError, build_session, run_session

    config, origin = load_config(args.session)
    config = apply_overrides(config, args.set or [])
    # the estimators' and the aligner's kernels are compiled on the first run (numba, ~10 s here), then loaded
    with err.status("building the session (the first run compiles the numba kernels, ~10 s)"):
        session = build_session(config)
    duration = session.settings.duration if args.duration is None else check_duration("--duration", args.duration)
    err.print(f"[bold]hapticlab run[/] {origin}: {duration:g} s, sensor {session.plugins['sensor']['name']}, "
              f"kinematics {session.plugins['kinematics']['name']}, estimator {session.estimator_name}, "
              f"haptic {session.plugins['haptic']['name']}  (Ctrl-C stops and keeps the recording)")
    try:
        if err.is_terminal:
            with Live(console=err, refresh_per_second=4, transient=False) as live:
                result = run_session(session, out=args.out, duration=duration,
                                     on_status=lambda s: live.update(_status_table(s)))
        else:
            result = run_session(session, out=args.out, duration=duration)
    except SessionError as exc:  # a device or estimator failed: one line, the recording is complete
        err.print(f"hapticlab run: session ended by an error: {exc}", markup=False, highlight=False)
        if exc.part.startswith("estimator"):  # an estimator's exception is a bug worth its traceback
            import traceback

            traceback.print_exception(exc.__cause__, file=sys.stderr)
        print(exc.result.path)
        return 1
    ending = "interrupted" if result.interrupted else "finished"
    table = Table(title=f"session {ending}", show_header=False)
    table.add_row("recording", str(result.path))
    table.add_row("duration", f"{result.duration_s:.2f} s")
    table.add_row("wrench samples", str(result.samples))
    table.add_row("poses", str(result.poses))
    table.add_row("force converged at sample", str(result.first_converged_force))
    table.add_row("torque converged at sample", str(result.first_converged_torque))
    table.add_row("contact samples", str(result.contact_samples))
    table.add_row("haptic force on", f"{result.haptic_on_s:.2f} s")
    for key, value in result.params.items():
        table.add_row(key, "[" + ", ".join(f"{v:.4g}" for v in value) + "]")
    table.add_row("events", str(len(result.events)))
    if result.overruns:
        table.add_row("loop overruns", f"{result.overruns} (see the overrun events)")
    err.print(table)
    print(result.path)
    return 0


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser("run", help="run a session from a preset name or TOML file (default: demo)")
    p.add_argument("session", nargs="?", default=None, help="preset name or path to a .toml file")
    p.add_argument("--duration", type=float, default=None, help="seconds to run (overrides the config)")
    p.add_argument("--out", default=None, help="recording path (.mcap)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config value, e.g. --set estimator.name=batch")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plugins", help="list every registered plugin by kind, with where it came from")
    p.set_defaults(func=cmd_plugins)
