"""``hapticlab emulate robotiq-ft300``: the FT 300 emulator (``robotiq_emulator.py``) as a command.

The first line printed is the pty's port, so a script or a test can read it and give it as
``sensor.port``; ``--fault KIND@SECONDS[:ARG]`` injects faults at world times; the last line counts
what it sent and injected.
"""

from __future__ import annotations

import argparse

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins.sensors.robotiq_emulator import FAULT_KINDS, FT300Emulator, ScheduledFault
from hapticlab.plugins.serving import serve_on_pty
from hapticlab.plugins.simworld.physics import SimWorld


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate robotiq-ft300`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument("--serial-number", default="FTS-4242", help="registers 510-513, LLL-NNNN (default FTS-4242)")
    parser.add_argument("--production-year", type=int, default=2026, help="register 514 (default 2026)")
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND@SECONDS[:ARG]",
        help=f"inject a fault at a world time ({', '.join(FAULT_KINDS)}), e.g. crc@5:3, garbage@6:64, stall@8:0.5, "
        "unplug@12; repeatable",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve ``world`` until Ctrl-C, SIGTERM or ``--duration``; the first line printed is the port to open."""
    try:
        faults = [ScheduledFault.parse(text) for text in args.fault]
        emulator = FT300Emulator(
            world, serial_number=args.serial_number, production_year=args.production_year, faults=faults
        )
    except ValueError as exc:
        raise ConfigError(f"emulate robotiq-ft300: {exc}") from None

    serve_on_pty(
        emulator,
        args.duration,
        lambda: (
            f"Robotiq FT 300 emulator on {emulator.port}: Modbus RTU slave 9, 100 Hz stream; world time starts "
            f"at the first byte a client sends; e.g. hapticlab run SESSION --set sensor.port={emulator.port}"
        ),
    )
    c = emulator.counts
    print(
        f"sent {c.frames} frames ({c.frames_corrupted} with a broken CRC, {c.frames_stalled} held back by a stall, "
        f"{c.garbage_bytes} garbage bytes, {c.bytes_dropped} bytes nobody read); {c.requests} Modbus request(s), "
        f"{c.exceptions} exception(s), {c.starts} stream start(s), {c.stops} stop(s)",
        flush=True,
    )
    return 0


@hookimpl
def register_emulators(register):
    register(
        "robotiq_ft300",  # the command line takes robotiq-ft300 too
        EmulatorCommand(
            help="Robotiq FT 300 on a pseudo-terminal: Modbus RTU registers and its 100 Hz stream",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
        ),
    )
