"""``hapticlab run`` and ``hapticlab plugins``: a live session with its status line, the plugin list.

While a session runs in a terminal, the ``r`` key re-arms a latched stop (the
status line says so); stdin is then in cbreak mode (keys arrive one by one,
unechoed, Ctrl-C still stops) and restored when the session ends.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from rich.console import Console

from hapticlab.core.host.registry import KINDS, Registry
from hapticlab.sessions.cli.errors import is_user_error
from hapticlab.sessions.cli.render import err

if TYPE_CHECKING:  # the tables are imported where drawn: `hapticlab --version` builds this module's parser
    from rich.table import Table

out = Console()


def cmd_plugins(args: argparse.Namespace) -> int:
    from rich.table import Table

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


REARM_KEY = b"r"
TARE_KEY = b"t"


class RearmKey:
    """The ``r`` (re-arm) and ``t`` (tare) keys on an interactive stdin, read without blocking (a context manager;
    inactive off a TTY).

    Attributes:
        active: stdin is a terminal in cbreak mode, read by :meth:`pressed`.
    """

    def __init__(self, stream: IO[Any] | None = None) -> None:
        self.stream = sys.stdin if stream is None else stream
        self.active = False
        self._saved: list[Any] | None = None  # the terminal's attributes while cbreak is set
        self._fd: int | None = None  # the terminal's descriptor, set with _saved and active

    def __enter__(self) -> RearmKey:
        try:
            import termios
            import tty

            fd = self.stream.fileno()
            if os.isatty(fd):
                self._saved = termios.tcgetattr(fd)
                self._fd = fd
                tty.setcbreak(fd)
                self.active = True
        except (ImportError, OSError, ValueError, AttributeError):  # no termios (Windows), no real stdin
            self.active = False
        return self

    def __exit__(self, *exc) -> None:
        if self._saved is not None:
            import termios

            assert self._fd is not None  # set with _saved
            # the terminal it was set on; gone (a hang-up) is nothing to restore, and must not hide the result
            with contextlib.suppress(termios.error, OSError):
                termios.tcsetattr(self._fd, termios.TCSADRAIN, self._saved)
            self._saved = None
        self.active = False

    def pressed(self) -> bool:
        """The ``r`` key was pressed since the last call (never waits; other keys are dropped)."""
        return REARM_KEY in self.typed()

    def typed(self) -> bytes:
        """The keys typed since the last call, lower case (never waits; b"" off a terminal)."""
        if not self.active:
            return b""
        fd = self._fd
        assert fd is not None  # set with active
        data = b""
        try:
            while select.select([fd], [], [], 0)[0]:
                chunk = os.read(fd, 64)
                if not chunk:
                    break
                data += chunk
        except (OSError, ValueError):  # the terminal hung up: no more keys, the session goes on
            self.active = False
            return b""
        return data.lower()


def _stdin_is_terminal() -> bool:
    """stdin is a terminal the keys can be read from (False when it is closed, absent or a file)."""
    try:
        return sys.stdin is not None and sys.stdin.isatty()
    except (ValueError, OSError):
        return False


def rearm_hint(key: bool, button: int) -> str:
    """How to re-arm a latched stop here: the ``r`` key when stdin is a terminal, the device's button if configured."""
    ways = (["press r"] if key else []) + ([f"the device's re-arm button ({button})"] if button >= 0 else [])
    return " or ".join(ways) if ways else "no key or button to re-arm (set haptic.rearm_button)"


def _status_table(status, hint: str = "") -> Table:
    from rich.table import Table

    table = Table.grid(padding=(0, 2))
    haptic = "[green]on[/]" if status.haptic_enabled else f"[yellow]off[/] ({status.reason})"
    if status.latched:
        haptic = f"[red]latched[/]: {hint or rearm_hint(False, -1)}"
    table.add_row(
        f"t {status.elapsed_s:6.1f} s",
        f"{status.samples} samples @ {status.rate_hz:6.0f} Hz",
        "force " + ("[green]converged[/]" if status.converged_force else "[yellow]converging[/]"),
        "torque " + ("[green]converged[/]" if status.converged_torque else "[yellow]converging[/]"),
        "[red]CONTACT[/]" if status.contact else "free",
        f"haptic {haptic}",
        *([f"robot {status.teleop}"] if status.teleop else []),
        f"{status.events} events",
        *([f"[red]{status.behind_s * 1e3:.0f} ms behind[/]"] if status.behind_s > 0 else []),
    )
    return table


def cmd_run(args: argparse.Namespace) -> int:
    from rich.live import Live
    from rich.table import Table
    from rich.text import Text

    from hapticlab.sessions.config import apply_overrides, load_config
    from hapticlab.sessions.live import SessionError, build_session, run_session
    from hapticlab.sessions.live.build import check_live_address, refuse_existing_outputs
    from hapticlab.sessions.settings import check_duration

    config, origin = load_config(args.session)
    config = apply_overrides(config, args.set or [])
    if args.live:  # before the build: a refused address costs no compile
        check_live_address(args.live, allow_network=args.allow_network)
    if args.out:  # before the build too; the estimator's saved state beside it once the build names the estimator
        refuse_existing_outputs(Path(args.out), saves_state=False)
    # the estimators' and the aligner's kernels are compiled on the first run (numba, ~10 s here), then loaded
    with err.status("building the session (the first run compiles the numba kernels, ~10 s)"):
        session = build_session(config)
    duration = session.settings.duration if args.duration is None else check_duration("--duration", args.duration)
    if args.out:  # before the banner: a refused --out is the only line
        refuse_existing_outputs(Path(args.out), saves_state=session.primary.saves is not None)
    err.print(
        f"[bold]hapticlab run[/] {origin}: {duration:g} s, sensor {session.plugins['sensor']['name']}, "
        f"kinematics {session.plugins['kinematics']['name']}, estimator {session.estimator_name}, "
        f"haptic {session.plugins['haptic']['name']}  (Ctrl-C stops and keeps the recording"
        + ("; r re-arms, t tares" if _stdin_is_terminal() else "")
        + ")"
    )
    live_at = args.live or ""
    if live_at:
        err.print(
            f"live view: ws://{live_at} (in Foxglove: Open connection → Foxglove WebSocket; "
            f"layout: docs/foxglove-layout.json)",
            markup=False,
            highlight=False,
        )
    try:
        with RearmKey() as key:
            hint = rearm_hint(key.active, session.haptic_settings.rearm_button)

            def on_status(status) -> None:
                typed = key.typed()
                if REARM_KEY in typed and status.rearm is not None:
                    status.rearm(f"key {REARM_KEY.decode()}")
                if TARE_KEY in typed and status.tare is not None:
                    status.tare(f"key {TARE_KEY.decode()}")
                if live is not None:
                    live.update(_status_table(status, hint))

            if err.is_terminal:
                with Live(console=err, refresh_per_second=4, transient=False) as live:
                    result = run_session(
                        session,
                        out=args.out,
                        duration=duration,
                        on_status=on_status,
                        live=live_at,
                        allow_network=args.allow_network,
                    )
            else:
                live = None
                result = run_session(
                    session,
                    out=args.out,
                    duration=duration,
                    on_status=on_status if key.active else None,
                    live=live_at,
                    allow_network=args.allow_network,
                )
    except SessionError as exc:  # a device or estimator failed: one line, the recording is complete
        err.print(f"hapticlab run: session ended by an error: {exc}", markup=False, highlight=False)
        if exc.part.startswith("estimator"):  # an estimator's exception is a bug worth its traceback
            import traceback

            traceback.print_exception(exc.__cause__, file=sys.stderr)
        print(exc.result.path)
        return 2 if is_user_error(exc.__cause__) else 1  # e.g. a haptic.port that does not exist: the user's to fix
    ending = "interrupted" if result.interrupted else "finished"
    table = Table(title=f"session {ending}", show_header=False)
    table.add_row("recording", str(result.path))
    table.add_row("duration", f"{result.duration_s:.2f} s")
    table.add_row("wrench samples", str(result.samples))
    table.add_row("poses", str(result.poses))
    table.add_row("force converged at sample", str(result.first_converged_force))
    table.add_row("torque converged at sample", str(result.first_converged_torque))
    weight = weight_identified(result.params)
    if weight:
        table.add_row("tool's weight identified", weight)
    table.add_row("contact samples", str(result.contact_samples))
    if result.held_out_samples is not None:  # refused, but lone: the sensor's noise, not a contact
        table.add_row("samples held out (lone outliers)", str(result.held_out_samples))
    table.add_row("haptic force on", f"{result.haptic_on_s:.2f} s")
    for name, value in result.params.items():  # (as Text: rich would take "[nan, nan, nan]" for a style tag)
        table.add_row(name, Text("[" + ", ".join(f"{v:.4g}" for v in value) + "]"))
    table.add_row("events", str(len(result.events)))
    if result.overruns:
        table.add_row("loop overruns", f"{result.overruns} (see the overrun events)")
    err.print(table)
    print(result.path)
    return 0


def weight_identified(params: dict[str, list[float]]) -> str:
    """What the motion identified of the tool's weight, for an estimator that reports it (``kalman``: its
    unidentified axes of gravity_force_B are NaN, its flag may be up before): "every axis", or which axes not;
    "" for one that does not report it."""
    if "gravity_force_B_std" not in params:
        return ""
    axes = [name for name, value in zip("xyz", params["gravity_force_B"]) if value != value]  # (NaN)
    if not axes:
        return "every axis"
    return f"not along B's {', '.join(axes)}" + (
        " (turn the tool about another axis)" if len(axes) < 3 else " (turn the tool)"
    )


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``hapticlab`` parser."""
    p = sub.add_parser("run", help="run a session from a preset name or TOML file (default: demo)")
    p.add_argument("session", nargs="?", default=None, help="preset name or path to a .toml file")
    p.add_argument("--duration", type=float, default=None, help="seconds to run (overrides the config)")
    p.add_argument("--out", default=None, help="recording path (.mcap)")
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config value, e.g. --set estimator.name=batch"
    )
    p.add_argument(
        "--live",
        nargs="?",
        const="127.0.0.1:8765",
        default=None,
        metavar="HOST:PORT",
        help="serve the session live to Foxglove over WebSocket (default 127.0.0.1:8765; "
        "needs the live extra: pip install 'hapticlab[live]')",
    )
    p.add_argument(
        "--allow-network",
        action="store_true",
        help="allow --live on a non-loopback address: anyone on the network then sees every topic, "
        "/haptic/command included (the live view has no authentication)",
    )
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("plugins", help="list every registered plugin by kind, with where it came from")
    p.set_defaults(func=cmd_plugins)
