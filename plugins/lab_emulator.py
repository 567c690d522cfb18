"""``hapticlab emulate lab``: a Net F/T and a UR arm served together from one simulated world on one clock.

The wrench the sensor reads is the one the arm's pose makes: both emulators
(``sensors/netft_emulator.py``, ``kinematics/ur_emulator.py``) take the same
world, and the arm's controller timestamp 0 is the sensor's first internal
sample. This is what the ``lab-emulated`` and ``teleop-lab-emulated`` presets
connect to. It sits beside ``serving.py`` rather than in either device's folder
because it belongs to both.

The first line printed names both addresses and the world's time 0 on the
monotonic clock (``t0_ns=...``; CLOCK_MONOTONIC is shared by every process of
the machine), so a test can compare a session's stamps with the world's physics.
"""

from __future__ import annotations

import argparse

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.types import EmulatorCommand
from hapticlab.plugins.kinematics.ur_emulator import UREmulator
from hapticlab.plugins.sensors.netft_emulator import NetFTEmulator
from hapticlab.plugins.sensors.netft_wire import RdtFault
from hapticlab.plugins.serving import serve_until_stopped
from hapticlab.plugins.simworld.physics import SimWorld


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate lab`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--netft",
        default="127.0.0.2",
        metavar="ADDRESS",
        help="the Net F/T's IPv4 address (default 127.0.0.2; loopback only, unless --allow-network)",
    )
    parser.add_argument("--rdt-port", type=int, default=49152, help="its RDT UDP port (49152)")
    parser.add_argument(
        "--http-port", type=int, default=8080, help="its netftapi2.xml HTTP port (8080: port 80 needs privileges)"
    )
    parser.add_argument("--rate", type=float, default=1000.0, help="its RDT rate, Hz (7000/n; default 1000)")
    parser.add_argument(
        "--ur",
        default="127.0.0.3",
        metavar="ADDRESS",
        help="the UR controller's IPv4 address, port 30004 (default 127.0.0.3; loopback only, unless --allow-network)",
    )
    parser.add_argument("--model", default="ur5e", help="the UR model (default ur5e: e-Series, 500 Hz)")
    parser.add_argument(
        "--netft-fault",
        action="append",
        default=[],
        metavar="KIND[,start=S][,duration=S][,every=N][,status=0x...]",
        help="a wire fault of the Net F/T, as emulate netft --fault; repeatable",
    )
    parser.add_argument(
        "--ur-stall",
        action="append",
        default=[],
        metavar="START,DURATION",
        help="the UR stream stalls over this window of world time, s: no data package, the connection open; repeatable",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def _window(text: str) -> tuple[float, float]:
    """A ``--ur-stall START,DURATION`` window, s."""
    try:
        start, duration = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--ur-stall {text!r}: expected START,DURATION in s") from None
    return start, duration


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve both devices on ``world`` until Ctrl-C, SIGTERM or ``--duration``; exit status 0."""
    try:
        faults = [RdtFault.parse(text) for text in args.netft_fault]
        stalls = [_window(text) for text in args.ur_stall]
        sensor = NetFTEmulator(world, args.netft, args.rdt_port, args.http_port, args.rate, faults=faults)
        arm = UREmulator(world, address=args.ur, model=args.model, stalls=stalls)
    except ValueError as exc:
        raise ConfigError(f"emulate lab: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"emulate lab: cannot serve on {args.netft} or {args.ur}: {exc.strerror or exc}") from None
    sensor.start()
    following = " following the targets written to its input registers (hapticlab_follow.script)"
    try:
        try:
            arm.start(t0_ns=sensor.t0_ns)  # one world time: the arm's timestamp 0 is the sensor's first sample
        except OSError as exc:
            raise ConfigError(f"emulate lab: cannot serve RTDE on {args.ur}:30004: {exc.strerror or exc}") from None
        try:
            serve_until_stopped(
                args.duration,
                ready=lambda: print(
                    f"lab: Net F/T on {args.netft} (RDT udp/{sensor.rdt_port} at {args.rate:g} Hz, "
                    f"netftapi2.xml http/{sensor.http_port}), UR {args.model} on {args.ur}:{arm.port}"
                    f"{following if arm.follows else ''}; "
                    f"t0_ns={sensor.t0_ns}",
                    flush=True,
                ),
            )
        finally:
            arm.stop()
    finally:
        sensor.stop()
    c = sensor.counts
    print(
        f"sent {c.sent} RDT records ({c.dropped} dropped, {c.duplicated} duplicated, {c.reordered} reordered, "
        f"{c.stalled} stalled, {c.status} with a status) and {arm.packages_sent} RTDE data packages "
        f"({arm.packages_stalled} stalled)",
        flush=True,
    )
    return 0


@hookimpl
def register_emulators(register):
    """Register the Net F/T and UR arm on one world as ``lab``."""
    register(
        "lab",
        EmulatorCommand(
            help="a Net F/T and a UR arm on one simulated world and one clock (the lab-emulated preset's devices)",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
            session="lab-emulated",
            listens_on=("netft", "ur"),
        ),
    )
