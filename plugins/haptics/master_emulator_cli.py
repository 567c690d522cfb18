"""``hapticlab emulate master``: the master emulator (``master_emulator.py``) as a command, with scheduled faults.

The first line printed is the pty's port, so a script or a test can read it and open the port;
``--fault KIND@SECONDS[:ARG]`` injects faults at set times (:class:`ScheduledFault`), and
``--log-forces`` writes every force received with when it came off the wire.
"""

from __future__ import annotations

import argparse
import os
import threading
from pathlib import Path

from hapticlab.core import hookimpl
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins import scheduled_fault
from hapticlab.plugins.haptics.handle_motion import PATHS, recorded_motion, scripted_motion
from hapticlab.plugins.haptics.master_emulator import MasterEmulator
from hapticlab.plugins.serving import serve_on_pty

FAULT_KINDS = ("crc", "garbage", "silent", "restart", "unplug")


class ScheduledFault(scheduled_fault.ScheduledFault):
    """A fault the command-line emulator injects ``at`` s after it starts.

    ``crc@T:N`` breaks the next N replies (default 1), ``garbage@T:N`` writes N
    noise bytes before the next reply (default 64), ``silent@T:D`` stops
    answering for D s (default: for good), ``restart@T`` forgets the
    handshake, ``unplug@T`` closes the pty's master side.
    """

    KINDS = FAULT_KINDS
    EXAMPLE = "crc@5:3 or unplug@10"

    def inject(self, emulator: MasterEmulator, stop: threading.Event) -> None:
        """Wait until the fault is due (or ``stop``), then inject it."""
        if stop.wait(max(0.0, self.at - emulator.now())):
            return
        if self.kind == "crc":
            emulator.corrupt_replies(int(self.arg or 1))
        elif self.kind == "garbage":
            emulator.garbage_before_reply(os.urandom(int(64 if self.arg is None else self.arg)))
        elif self.kind == "silent":
            emulator.stop_answering()
            if self.arg is not None and not stop.wait(self.arg):
                emulator.stop_answering(False)
        elif self.kind == "restart":
            emulator.restart()
        else:
            emulator.unplug()
        print(f"{emulator.now():.3f} s: injected {self.kind}", flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate master``."""
    parser.add_argument(
        "--protocol",
        choices=("hapticlab", "inverse3"),
        default="hapticlab",
        help="wire protocol: ours (framed, CRC-16) or Haply's Inverse3 (default hapticlab)",
    )
    parser.add_argument(
        "--path",
        default="circle",
        metavar="circle|figure8|hold|press|FILE.csv",
        help="the handle's motion in D: scripted, or a CSV of t,x,y,z (s, m) played in a loop",
    )
    parser.add_argument("--radius", type=float, default=0.03, help="scripted path size, m (default 0.03)")
    parser.add_argument("--period", type=float, default=8.0, help="scripted path lap time, s (default 8)")
    parser.add_argument(
        "--center",
        type=float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("X", "Y", "Z"),
        help="scripted path centre in D, m",
    )
    parser.add_argument("--max-force", type=float, default=8.0, help="the device's force limit, N (default 8)")
    parser.add_argument("--device-id", type=int, default=0x4C41, help="device id in the handshake answer")
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND@SECONDS[:ARG]",
        help=f"inject a fault ({', '.join(FAULT_KINDS)}), e.g. crc@5:3, silent@8:0.5, unplug@12; repeatable",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")
    parser.add_argument(
        "--log-forces",
        default=None,
        metavar="FILE.csv",
        help="on exit, write the forces received (the last 100 000) with when each came off the wire (received_ns "
        "on this machine's monotonic clock, fx, fy, fz) to a new CSV (bench/haptic_wire.py)",
    )


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C, SIGTERM or ``--duration``; the first line printed is the port to open."""
    from hapticlab.core.errors import ConfigError

    try:
        motion = (
            recorded_motion(args.path)
            if args.path not in PATHS
            else scripted_motion(args.path, args.radius, args.period, tuple(args.center))
        )
        emulator = MasterEmulator(args.protocol, motion, args.max_force, args.device_id)
        faults = [ScheduledFault.parse(text) for text in args.fault]
        log = args.log_forces
        if log is not None and Path(log).exists():
            raise ValueError(f"--log-forces {log}: exists; give a new file name")
    except ValueError as exc:
        raise ConfigError(f"emulate master: {exc}") from None
    serve_on_pty(
        emulator,
        args.duration,
        lambda: (
            f"{args.protocol} master emulator on {emulator.port}: handle on {args.path}, max "
            f"{args.max_force:g} N; e.g. hapticlab run --set haptic.name=serial --set haptic.port={emulator.port}"
            f" --set haptic.protocol={args.protocol}"
        ),
        faults,
    )
    c = emulator.counts
    print(
        f"{c.forces} force command(s), {c.heartbeats} heartbeat(s), {c.hellos} handshake(s); {c.crc_errors} CRC "
        f"error(s), {c.naks_sent} NAK(s) sent, {c.clamped} clamped, {c.watchdog_trips} watchdog trip(s); "
        f"{c.replies_corrupted} reply(ies) corrupted, {c.requests_ignored} request(s) ignored"
    )
    if log is not None:
        print(f"{emulator.write_forces(log)} force(s) with their receipt times written to {log}", flush=True)
    return 0


@hookimpl
def register_emulators(register):
    register(
        "master",
        EmulatorCommand(
            help="serial haptic master on a pseudo-terminal: hapticlab's framed protocol or Haply Inverse3",
            add_arguments=add_arguments,
            run=run,
        ),
    )
