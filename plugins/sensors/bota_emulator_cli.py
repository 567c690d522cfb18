"""``hapticlab emulate bota``: the Bota serial sensor emulator (``bota_emulator.py``) as a command, with faults.

The first line printed is the pty's port, so a script or a test can read it and open the port;
``--fault KIND@SECONDS[:ARG]`` injects faults at set times of the world's clock (from the first ``R``: a
session's start), as the Net F/T emulator's faults act over windows of world time.
"""

from __future__ import annotations

import argparse
import os
import threading
import time

from hapticlab.core import hookimpl
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins import scheduled_fault
from hapticlab.plugins.sensors import bota_protocol as bp
from hapticlab.plugins.sensors.bota_emulator import BotaEmulator
from hapticlab.plugins.serving import serve_on_pty
from hapticlab.plugins.simworld.physics import SimWorld

FAULT_KINDS = ("crc", "garbage", "overrange", "invalid", "stall", "unplug")


class ScheduledFault(scheduled_fault.ScheduledFault):
    """A fault injected ``at`` s of world time (after the first ``R``).

    ``crc@T:N`` breaks the CRC of the next N frames (default 1), ``garbage@T:N`` writes N noise
    bytes into the stream (default 64), ``overrange@T:D`` and ``invalid@T:D`` set that status bit
    for D s (default 0.1), ``stall@T:D`` sends nothing for D s (default 0.5), ``unplug@T`` closes
    the pty's master side.
    """

    KINDS = FAULT_KINDS
    EXAMPLE = "crc@5:3 or stall@8:0.5"

    def inject(self, emulator: BotaEmulator, stop: threading.Event) -> None:
        """Wait until the fault is due on the world's clock (from the first ``R``) or ``stop``, then inject it."""
        while emulator.run_ns is None:
            if stop.wait(0.01):
                return
        started = emulator.run_ns * 1e-9
        if stop.wait(max(0.0, started + self.at - time.monotonic())):
            return
        if self.kind == "crc":
            emulator.corrupt_frames(int(self.arg or 1))
        elif self.kind == "garbage":
            emulator.garbage(os.urandom(int(64 if self.arg is None else self.arg)))
        elif self.kind in ("overrange", "invalid"):
            bits = bp.STATUS_OVERRANGE if self.kind == "overrange" else bp.STATUS_INVALID
            emulator.set_status(bits, 0.1 if self.arg is None else self.arg)
        elif self.kind == "stall":
            emulator.stall(0.5 if self.arg is None else self.arg)
        else:
            emulator.unplug()
        print(f"{time.monotonic() - started:.3f} s: injected {self.kind}", flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate bota`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--sinc-length",
        type=int,
        default=64,
        help="the sinc length at power-on (the rate: 51200/N Hz; default 64: 800 Hz); a client's f command changes it",
    )
    parser.add_argument("--temperature", type=float, default=28.0, help="board temperature at power-on, °C")
    parser.add_argument("--warm-up", type=float, default=3.0, help="how much the board warms up, °C (default 3)")
    parser.add_argument("--warm-up-time", type=float, default=600.0, help="the warm-up's time constant, s")
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND@SECONDS[:ARG]",
        help=f"inject a fault ({', '.join(FAULT_KINDS)}), e.g. crc@5:3, stall@8:0.5, unplug@12; repeatable",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve ``world`` until Ctrl-C, SIGTERM or ``--duration``; the first line printed is the port to open."""
    from hapticlab.core.errors import ConfigError

    try:
        faults = [ScheduledFault.parse(text) for text in args.fault]
        emulator = BotaEmulator(world, args.sinc_length, args.temperature, args.warm_up, args.warm_up_time)
    except ValueError as exc:
        raise ConfigError(f"emulate bota: {exc}") from None
    serve_on_pty(
        emulator,
        args.duration,
        lambda: (
            f"Bota serial sensor emulator on {emulator.port}: {emulator.rate_hz:g} Hz (sinc {emulator.sinc_length}); "
            f"e.g. hapticlab run --set sensor.name=bota --set sensor.port={emulator.port}"
        ),
        faults,
    )
    c = emulator.counts
    print(
        f"sent {c.frames} frames ({c.corrupted} corrupted, {c.status_frames} with a status, {c.stalled_frames} "
        f"stalled, {c.garbage_bytes} noise bytes, {c.unsent_bytes} bytes no one read); {c.commands} command(s), "
        f"{c.refused} refused, {c.unknown_bytes} unknown byte(s); "
        + (
            f"world time 0 at the first R, run_after_boot_ns={emulator.run_ns - emulator.boot_ns}"
            if emulator.run_ns is not None
            else "no R received: the world stayed at time 0"
        ),
        flush=True,
    )
    return 0


@hookimpl
def register_emulators(register):
    register(
        "bota",
        EmulatorCommand(
            help="Bota Systems serial F/T sensor (BFT-*-SER binary frames) on a pseudo-terminal",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
        ),
    )
