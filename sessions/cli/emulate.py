"""``hapticlab emulate``: a real device's wire protocol on a loopback address, fed by the simulated world.

Each emulator lives beside its plugin (``plugins/<kind>/<device>_emulator.py``)
and registers an ``EmulatorCommand`` (``add_arguments(parser)``, ``run(args)``)
through the ``register_emulators`` hook, so a third party adds one as it adds
a sensor; this module makes a subcommand of each, and adds ``lab``: a Net
F/T and a UR arm served together from one world on one clock, so the wrench
the sensor reads is the one the arm's pose makes (what the ``lab-emulated``
preset connects to). An emulator prints where it
listens on its first line, then serves until Ctrl-C, SIGTERM or
``--duration``; the vendor's own client (``pynetft``, ``ur-rtde``) connects to
it as to the device.
"""

from __future__ import annotations

import argparse

import pluggy

from hapticlab.core.host.registry import Registry


def add_commands(sub: argparse._SubParsersAction, pm: pluggy.PluginManager) -> None:
    """``emulate`` and one subcommand per registered emulator (``register_emulators``), and ``lab``."""
    parser = sub.add_parser(
        "emulate",
        help="serve a real device's protocol on loopback, fed by the simulator",
        description=__doc__.split("\n\n")[0],
    )
    devices = parser.add_subparsers(dest="device", required=True, metavar="DEVICE")
    registry = Registry(pm)
    for name in registry.names("emulator"):
        emulator = registry.get("emulator", name).factory
        device = devices.add_parser(name, help=emulator.help, description=emulator.help)
        emulator.add_arguments(device)
        device.set_defaults(func=emulator.run)
    lab = devices.add_parser(
        "lab",
        help="a Net F/T and a UR arm on one simulated world and one clock (the lab-emulated preset's devices)",
        description="A Net F/T (RDT/UDP and netftapi2.xml) and a UR controller (RTDE) "
        "served together, fed by one simulated world on one clock.",
    )
    lab.add_argument(
        "--session",
        default="lab-emulated",
        help="preset name or TOML file whose [world] both devices live in (default: lab-emulated)",
    )
    lab.add_argument("--netft", default="127.0.0.2", metavar="ADDRESS", help="the Net F/T's address (127.0.0.2)")
    lab.add_argument("--rdt-port", type=int, default=49152, help="its RDT UDP port (49152)")
    lab.add_argument(
        "--http-port", type=int, default=8080, help="its netftapi2.xml HTTP port (8080: port 80 needs privileges)"
    )
    lab.add_argument("--rate", type=float, default=1000.0, help="its RDT rate, Hz (7000/n; default 1000)")
    lab.add_argument(
        "--ur", default="127.0.0.3", metavar="ADDRESS", help="the UR controller's address, port 30004 (127.0.0.3)"
    )
    lab.add_argument("--model", default="ur5e", help="the UR model (default ur5e: e-Series, 500 Hz)")
    lab.add_argument(
        "--netft-fault",
        action="append",
        default=[],
        metavar="KIND[,start=S][,duration=S][,every=N][,status=0x...]",
        help="a wire fault of the Net F/T, as emulate netft --fault; repeatable",
    )
    lab.add_argument(
        "--ur-stall",
        action="append",
        default=[],
        metavar="START,DURATION",
        help="the UR stream stalls over this window of world time, s: no data package, the connection open; repeatable",
    )
    lab.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")
    lab.set_defaults(func=run_lab)


def run_lab(args: argparse.Namespace) -> int:
    """Serve both devices until Ctrl-C, SIGTERM or ``--duration``.

    The first line names both addresses and the world's time 0 on the monotonic
    clock (``t0_ns``; CLOCK_MONOTONIC is shared by every process of the machine),
    so a test can compare a session's stamps with the world's physics.
    """
    from hapticlab.core.host.registry import ConfigError
    from hapticlab.plugins.kinematics.ur_emulator import UREmulator
    from hapticlab.plugins.sensors.netft_emulator import NetFTEmulator, RdtFault
    from hapticlab.plugins.serving import serve_until_stopped
    from hapticlab.plugins.simworld import SimWorld
    from hapticlab.sessions.config import load_config

    def window(text: str) -> tuple[float, float]:  # --ur-stall START,DURATION
        try:
            start, duration = (float(x) for x in text.split(","))
        except ValueError:
            raise ValueError(f"--ur-stall {text!r}: expected START,DURATION in s") from None
        return start, duration

    config, _ = load_config(args.session)
    try:
        faults = [RdtFault.parse(text) for text in args.netft_fault]
        stalls = [window(text) for text in args.ur_stall]
        world = SimWorld.from_config(config.get("world"))
        sensor = NetFTEmulator(world, args.netft, args.rdt_port, args.http_port, args.rate, faults=faults)
        arm = UREmulator(world, address=args.ur, model=args.model, stalls=stalls)
    except ValueError as exc:
        raise ConfigError(f"emulate lab: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"emulate lab: cannot serve on {args.netft} or {args.ur}: {exc.strerror or exc}") from None
    sensor.start()
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
                    f"{' following the targets written to its input registers (hapticlab_follow.script)' if arm.follows else ''}; "
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
