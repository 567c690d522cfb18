"""The ``hapticlab`` command line.

Every command turns a bad input (config key, CSV row, file) into one line
naming the problem and exit status 2; nothing already recorded is lost.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rich.console import Console
from rich.live import Live
from rich.table import Table

import hapticlab
from hapticlab.core.plugins import KINDS, PluginError, Registry

err = Console(stderr=True)
out = Console()


class UserError(Exception):
    """An error the user can fix; printed as one line."""


def _user_errors() -> tuple[type[BaseException], ...]:
    from .csvimport import CsvError
    from .recording import RecordingError

    return (PluginError, CsvError, RecordingError, UserError, ValueError, FileNotFoundError,
            FileExistsError)


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
    )
    return table


def cmd_run(args: argparse.Namespace) -> int:
    from .config import apply_overrides, load_config
    from .run import build_session, run_session

    config, origin = load_config(args.session)
    config = apply_overrides(config, args.set or [])
    session = build_session(config)
    duration = args.duration if args.duration is not None else session.settings.duration
    err.print(f"[bold]hapticlab run[/] {origin}: {duration:g} s, sensor {session.plugins['sensor']['name']}, "
              f"kinematics {session.plugins['kinematics']['name']}, estimator {session.estimator_name}, "
              f"haptic {session.plugins['haptic']['name']}  (Ctrl-C stops and keeps the recording)")
    if err.is_terminal:
        with Live(console=err, refresh_per_second=4, transient=False) as live:
            result = run_session(session, out=args.out, duration=duration,
                                 on_status=lambda s: live.update(_status_table(s)))
    else:
        result = run_session(session, out=args.out, duration=duration)
    table = Table(title=f"session {'interrupted' if result.interrupted else 'finished'}", show_header=False)
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
    err.print(table)
    print(result.path)
    return 0


def cmd_compensate(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from .compensate import compensate

    with Progress(console=err, transient=True, disable=not err.is_terminal) as progress:
        task = progress.add_task(f"compensating {Path(args.input).name}", total=None)
        result = compensate(
            args.input, args.output, estimator_name=args.estimator, overrides=args.set or [],
            params_out=args.params_out,
            progress=lambda done, total: progress.update(task, completed=done, total=total),
        )
    for note in result.notes:
        err.print(f"note: {note}")
    def fmt(values, unit):
        if all(v != v for v in values):  # NaN: that stage never converged
            return "n/a (not converged)"
        return "[" + ", ".join(f"{x:.4g}" for x in values) + f"] {unit}"

    err.print(f"{Path(args.input).name}: {result.rows} rows → {args.output} ({args.estimator}); "
              f"force converged at sample {result.first_converged_force}, torque at "
              f"{result.first_converged_torque}")
    err.print(f"RMS contact wrench on no-contact rows after convergence: force "
              f"{fmt(result.rms_force_S, 'N')}, torque {fmt(result.rms_torque_S, 'N·m')}")
    return 0


def cmd_recover(args: argparse.Namespace) -> int:
    from .recording import recover

    counts = recover(args.broken, args.output)
    err.print(f"recovered {counts.get('messages', 0)} messages into {args.output}")
    for topic, n in sorted(counts.get("topics", {}).items()):
        err.print(f"  {topic}: {n}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hapticlab",
        description="Haptic teleoperation for robotic-surgery training: real-time F/T compensation, "
                    "recorded sessions.",
    )
    parser.add_argument("--version", action="version", version=f"hapticlab {hapticlab.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("run", help="run a session from a preset name or TOML file (default: demo)")
    p.add_argument("session", nargs="?", default=None, help="preset name or path to a .toml file")
    p.add_argument("--duration", type=float, default=None, help="seconds to run (overrides the config)")
    p.add_argument("--out", default=None, help="recording path (.mcap)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a config value, e.g. --set estimator.name=batch")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plugins", help="list every registered plugin by kind, with where it came from")
    p.set_defaults(func=cmd_plugins)

    p = sub.add_parser("compensate", help="run an estimator offline over a CSV or MCAP recording")
    p.add_argument("input", help="CSV (import contract) or .mcap recording")
    p.add_argument("-o", "--output", required=True, help="output CSV of the contact wrench per row")
    p.add_argument("--estimator", default="rls", help="estimator name (default: rls)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="estimator option, e.g. --set estimator.force_threshold=2")
    p.add_argument("--params-out", default=None, help="write the final parameters as JSON")
    p.set_defaults(func=cmd_compensate)

    p = sub.add_parser("recover", help="salvage a recording whose writer died")
    p.add_argument("broken", help="the damaged .mcap")
    p.add_argument("-o", "--output", required=True, help="where to write the recovered .mcap")
    p.set_defaults(func=cmd_recover)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        err.print("interrupted")
        return 130
    except _user_errors() as exc:
        message = str(exc).strip().replace("\n", " ")
        print(f"hapticlab {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
