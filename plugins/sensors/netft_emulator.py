"""A protocol-faithful ATI Net F/T fed by the simulated world: RDT over UDP and ``netftapi2.xml`` over HTTP.

It speaks the wire of ``netft_protocol.py``: start (0 samples: until
stopped), stop and bias requests, answered from the same socket with RDT
records; ``rdt_sequence`` from 1 with every start request, ``ft_sequence``
counting the internal samples at 7000/s since the emulator started (it goes
on counting between streams and is decimated with the RDT rate). The HTTP page
(default port 80) gives ``prodname``, ``cfgcpf``, ``cfgcpt``, ``scfgfu``,
``scfgtu``, ``comrdtrate``, ``runrate``, ``runstat`` and ``cfgmr``.

The readings are the ``sim`` sensor's (:class:`~hapticlab.plugins.sensors.sim.SimSensor`)
at the internal rate, so the physics and the world's injected faults
(``[[world.faults]]``) are the session's. On top of those, wire faults
(``netft_faults.py``) drop, duplicate and reorder records, set status bits,
stall ft_sequence or saturate the counts.

Records are sent in bursts about once a millisecond: every sample whose time
(on the monotonic clock, from the emulator's start) has come goes out, so the
average rate is exact whatever the scheduler does. Run it as
``hapticlab emulate netft --address 127.0.0.x`` (:func:`add_arguments`,
:func:`run`; the host gives it the session's world) or from Python::

    with NetFTEmulator(world, address="127.0.0.20", rdt_port=0, http_port=0) as emu:
        ...  # emu.rdt_port, emu.http_port: the ports it got
"""

from __future__ import annotations

import argparse
import select
import socket
import threading
import time
from http.server import ThreadingHTTPServer

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import OptionError, is_number
from hapticlab.core.types import STATUS_SATURATED, EmulatorCommand
from hapticlab.plugins.sensors.netft_protocol import (
    ATI_ERROR_SUMMARY,
    ATI_SATURATION,
    CMD_BIAS,
    CMD_START,
    CMD_STOP,
    FORCE_UNITS,
    FT_RATE_HZ,
    RDT_HEADER,
    RDT_PORT,
    REQUEST,
    TORQUE_UNITS,
    Calibration,
    configuration_handler,
    configuration_xml,
)
from hapticlab.plugins.sensors.netft_wire import FAULT_KINDS, INT32_MAX, RdtFault, RdtSender
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.serving import serve_until_stopped
from hapticlab.plugins.simworld.physics import SimWorld

BURST_S = 0.001
"""Records go out in bursts this far apart, s."""


class NetFTEmulator:
    """An emulated Net F/T: RDT over UDP and its XML page over HTTP, on one IPv4 address.

    Parameters
    ----------
    world : the simulated world the sensor sits in (its physics and faults).
    address : the IPv4 address to serve on (127.0.0.x keeps it on this machine).
    rdt_port, http_port : UDP and TCP ports; 0 picks a free one (see :attr:`rdt_port` after start).
    rdt_rate_hz : RDT output rate (``comrdtrate``), Hz; 7000 divided by a whole number.
    counts_per_force, counts_per_torque : the calibration (``cfgcpf``, ``cfgcpt``), counts per unit.
    force_unit, torque_unit : ``scfgfu`` and ``scfgtu`` (e.g. ``N`` and ``Nm``, ``N-mm``, ``lbf``).
    faults : wire faults to inject.
    ft_sequence_start : the ft_sequence of the first internal sample (a device up for a while).
    product_name : ``prodname``.
    """

    def __init__(
        self,
        world: SimWorld,
        address: str = "127.0.0.1",
        rdt_port: int = RDT_PORT,
        http_port: int = 80,
        rdt_rate_hz: float = FT_RATE_HZ,
        counts_per_force: float = 1_000_000.0,
        counts_per_torque: float = 1_000_000.0,
        force_unit: str = "N",
        torque_unit: str = "Nm",
        faults: tuple[RdtFault, ...] | list[RdtFault] = (),
        ft_sequence_start: int = 0x7FFF_0000,
        product_name: str = "Net F/T emulator (hapticlab)",
    ):
        decimation = FT_RATE_HZ / rdt_rate_hz if is_number(rdt_rate_hz) and rdt_rate_hz > 0 else 0.0
        if not (decimation >= 1 and abs(decimation - round(decimation)) < 1e-9):
            raise OptionError(
                "rdt_rate_hz", f"must be {FT_RATE_HZ:g} Hz divided by a whole number, got {rdt_rate_hz!r}"
            )
        Calibration.checked(counts_per_force, counts_per_torque, force_unit, torque_unit)  # scfgtu: as given
        self.world = world
        self.address = address
        self.rdt_rate_hz = float(rdt_rate_hz)
        self.decimation = round(decimation)
        self.counts_per_force = float(counts_per_force)
        self.counts_per_torque = float(counts_per_torque)
        self.force_unit, self.torque_unit = force_unit, torque_unit
        self.faults = tuple(faults)
        self.ft_sequence_start = int(ft_sequence_start)
        self.product_name = product_name
        # counts per SI unit (N, N·m), per axis
        self._counts_per_si = np.array(
            [counts_per_force / FORCE_UNITS[force_unit]] * 3 + [counts_per_torque / TORQUE_UNITS[torque_unit]] * 3
        )
        saturation = np.concatenate([world.sensor.saturation_force_S, world.sensor.saturation_torque_S])
        self._saturation_counts = np.minimum(np.rint(saturation * self._counts_per_si), INT32_MAX).astype(np.int64)
        self._sensor = SimSensor(FT_RATE_HZ, world=world)
        self.bias_counts = np.zeros(6, dtype=np.int64)
        """(6,) the software bias subtracted from every record, counts (set by a bias request)."""
        self.bias_ft_sequence: int | None = None
        """The ft_sequence of the reading the last bias request took (records after it are biased)."""
        self.t0_ns: int | None = None
        """Monotonic time of internal sample 0 (world time 0), ns."""
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        self._udp.bind((address, rdt_port))
        self._http = ThreadingHTTPServer((address, http_port), configuration_handler(self.xml))
        self._http.daemon_threads = True
        self.rdt_port = self._udp.getsockname()[1]
        self.http_port = self._http.server_address[1]
        self._wire = RdtSender(self._udp, self.faults, self._saturation_counts)
        self.counts = self._wire.counts
        """What it did on the wire since it started (:class:`~hapticlab.plugins.sensors.netft_wire.EmulatorCounts`)."""
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._streaming = False
        self._remaining = 0  # records left of a counted start request (0: until stopped)
        self._lock = threading.Lock()
        self._muted = False
        self.muted_ns: list[int | None] = [None, None]

    # ------------------------------------------------------------------ life cycle

    def start(self) -> NetFTEmulator:
        """Start the device's clock and serve RDT and HTTP in background threads."""
        self.t0_ns = time.monotonic_ns()
        self._sensor.open(self.t0_ns)
        self._threads = [
            threading.Thread(target=self._serve_rdt, name="netft-emulator-rdt", daemon=True),
            threading.Thread(
                target=self._http.serve_forever, kwargs={"poll_interval": 0.05}, name="netft-emulator-http", daemon=True
            ),
        ]
        for thread in self._threads:
            thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the sockets."""
        self._stop.set()
        if self._threads:  # serve_forever runs: ask it to end
            self._http.shutdown()
        for thread in self._threads:
            thread.join()
        self._http.server_close()
        self._udp.close()

    def __enter__(self) -> NetFTEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def streaming(self) -> bool:
        """Whether a client asked for records and is getting them."""
        return self._streaming

    def mute(self, muted: bool = True) -> None:
        """Pull (or plug back) the cable: while muted nothing is sent, though the device samples on.

        :attr:`muted_ns` keeps the monotonic times of the last mute and unmute, ns.
        """
        with self._lock:
            self._muted = muted
            self.muted_ns[0 if muted else 1] = time.monotonic_ns()

    @property
    def client(self) -> tuple[str, int] | None:
        """Where the records go: the address of the last start request."""
        return self._wire.client

    @property
    def last_ft_sequence(self) -> int | None:
        """The ft_sequence of the last record sent (None before the first)."""
        return None if self._wire.last is None else self._wire.last[0]

    @property
    def rdt_sequence(self) -> int:
        """The rdt_sequence of the last record sent in the current stream (0 before its first)."""
        return self._wire.rdt_sequence

    def world_time(self, ft_sequence: int) -> float:
        """The world time of the internal sample ``ft_sequence``, s (as the ``sim`` sensor times it)."""
        i = (int(ft_sequence) - self.ft_sequence_start) % 2**32
        return float(np.rint(i * (1e9 / FT_RATE_HZ))) / 1e9

    def counts_of(self, force_S: np.ndarray, torque_S: np.ndarray) -> np.ndarray:
        """(N, 6) int64 counts of readings in SI (N, N·m), before the software bias."""
        wrench = np.concatenate([np.atleast_2d(force_S), np.atleast_2d(torque_S)], axis=1)
        return np.rint(np.nan_to_num(wrench) * self._counts_per_si).astype(np.int64)

    def xml(self) -> bytes:
        """The ``netftapi2.xml`` page."""
        rating = np.concatenate(
            [
                self.world.sensor.saturation_force_S / FORCE_UNITS[self.force_unit],
                self.world.sensor.saturation_torque_S / TORQUE_UNITS[self.torque_unit],
            ]
        )
        fields = {
            "prodname": self.product_name,
            "runstat": "0x00000000",
            "runrate": f"{FT_RATE_HZ:g}",
            "comrdtrate": f"{self.rdt_rate_hz:g}",
            "cfgcpf": f"{self.counts_per_force:g}",
            "cfgcpt": f"{self.counts_per_torque:g}",
            "scfgfu": self.force_unit,
            "scfgtu": self.torque_unit,
            "cfgmr": ";".join(f"{v:g}" for v in rating),
        }
        return configuration_xml(fields)

    # ------------------------------------------------------------------ RDT

    def _serve_rdt(self) -> None:
        burst_ns = int(BURST_S * 1e9)
        due_ns: int = self.t0_ns  # type: ignore[assignment]  # started: t0_ns is set
        while not self._stop.is_set():
            now_ns = time.monotonic_ns()
            if now_ns >= due_ns:
                self._burst(now_ns)
                due_ns += burst_ns
                if due_ns <= now_ns:  # fell behind (a long pause): catch up in one burst, keep the schedule
                    due_ns = now_ns + burst_ns
            wait_s = max(0.0, (due_ns - time.monotonic_ns()) * 1e-9)
            try:
                ready, _, _ = select.select([self._udp], [], [], min(wait_s, 0.05))
            except (OSError, ValueError):
                return
            if ready:
                self._request()

    def _request(self) -> None:
        try:
            data, sender = self._udp.recvfrom(64)
        except OSError:
            return
        if len(data) != REQUEST.size:
            self.counts.ignored += 1
            return
        header, command, count = REQUEST.unpack(data)
        if header != RDT_HEADER or command not in (CMD_START, CMD_STOP, CMD_BIAS):
            self.counts.ignored += 1
            return
        with self._lock:
            if command == CMD_START:
                self._wire.start_stream(sender)
                self._streaming, self._remaining = True, count
                self.counts.starts += 1
            elif command == CMD_STOP:
                self._streaming = False
                self.counts.stops += 1
            else:
                last = self._wire.last
                if last is not None:
                    self.bias_counts = last[1] + self.bias_counts  # the current unbiased reading
                    self.bias_ft_sequence = last[0]
                self.counts.biases += 1

    def _burst(self, now_ns: int) -> None:
        """Sample the world up to now; send the due records if a client is streaming."""
        samples = self._sensor.read(now_ns)  # the device samples whether anyone listens or not
        with self._lock:
            if not self._streaming or self._wire.client is None or self._muted:
                return
            samples = [s for s in samples if s.seq % self.decimation == 0]
            if not samples:
                return
            counts = self.counts_of(np.array([s.force_S for s in samples]), np.array([s.torque_S for s in samples]))
            for sample, raw in zip(samples, counts):
                t = (sample.t_ns - self.t0_ns) / 1e9  # type: ignore[operator]  # started: t0_ns is set
                status = ATI_SATURATION | ATI_ERROR_SUMMARY if sample.status & STATUS_SATURATED else 0
                if not (np.isfinite(sample.force_S).all() and np.isfinite(sample.torque_S).all()):
                    status |= ATI_SATURATION | ATI_ERROR_SUMMARY  # the A/D gave no number
                raw = np.clip(raw, -self._saturation_counts, self._saturation_counts)
                self._wire.send(t, (self.ft_sequence_start + sample.seq) % 2**32, status, raw, self.bias_counts)
                if self._remaining:
                    self._remaining -= 1
                    if self._remaining == 0:
                        self._streaming = False
                        break


# --------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate netft`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--address",
        default="127.0.0.1",
        help="IPv4 address to serve on (default 127.0.0.1); a loopback one (127.0.0.x) only: another address "
        "of this machine (0.0.0.0: all of them) serves the network, with --allow-network",
    )
    parser.add_argument("--rdt-port", type=int, default=RDT_PORT, help="UDP port of the RDT stream (default 49152)")
    parser.add_argument("--http-port", type=int, default=80, help="TCP port of netftapi2.xml (default 80)")
    parser.add_argument("--rate", type=float, default=FT_RATE_HZ, help="RDT output rate, Hz (7000/n; default 7000)")
    parser.add_argument("--counts-per-force", type=float, default=1_000_000.0, help="cfgcpf, counts per force unit")
    parser.add_argument("--counts-per-torque", type=float, default=1_000_000.0, help="cfgcpt, counts per torque unit")
    parser.add_argument("--force-unit", default="N", choices=sorted(FORCE_UNITS), help="scfgfu")
    parser.add_argument("--torque-unit", default="Nm", choices=sorted(TORQUE_UNITS), help="scfgtu")
    parser.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND[,start=S][,duration=S][,every=N][,status=0x...]",
        help=f"inject a wire fault ({', '.join(FAULT_KINDS)}); repeatable",
    )
    parser.add_argument("--duration", type=float, default=None, help="serve this long, s (default: until Ctrl-C)")


def run(args: argparse.Namespace, world: SimWorld) -> int:
    """Serve ``world`` until Ctrl-C, SIGTERM or ``--duration``; the first line printed names the address and
    ports."""
    try:
        faults = [RdtFault.parse(text) for text in args.fault]
        emulator = NetFTEmulator(
            world,
            args.address,
            args.rdt_port,
            args.http_port,
            args.rate,
            args.counts_per_force,
            args.counts_per_torque,
            args.force_unit,
            args.torque_unit,
            faults,
        )
    except ValueError as exc:
        raise ConfigError(f"emulate netft: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"emulate netft: cannot serve on {args.address}: {exc.strerror or exc}") from None
    with emulator:
        serve_until_stopped(
            args.duration,
            ready=lambda: print(
                f"netft emulator on {emulator.address}: RDT udp/{emulator.rdt_port}, "
                f"netftapi2.xml http/{emulator.http_port}",
                flush=True,
            ),
        )
    c = emulator.counts
    print(
        f"sent {c.sent} records ({c.dropped} dropped, {c.duplicated} duplicated, {c.reordered} reordered, "
        f"{c.stalled} stalled, {c.status} with a status); {c.starts} start, {c.stops} stop, "
        f"{c.biases} bias request(s)"
    )
    return 0


@hookimpl
def register_emulators(register):
    register(
        "netft",
        EmulatorCommand(
            help="ATI Net F/T: RDT over UDP and netftapi2.xml over HTTP, up to 7000 samples/s",
            add_arguments=add_arguments,
            run=run,
            needs_world=True,
            listens_on=("address",),
        ),
    )
