"""A protocol-faithful ATI Net F/T on loopback, fed by the simulated world.

What it speaks (ATI Net F/T manual, RDT and XML interfaces):

* **RDT over UDP** (default port 49152): 8-byte big-endian requests
  (``uint16 0x1234, uint16 command, uint32 sample_count``; command 0x0002
  starts real-time streaming, 0 samples meaning "until stopped", 0x0000 stops,
  0x0042 sets the software bias to the current reading), answered from the
  same socket with 36-byte big-endian records (``uint32 rdt_sequence, uint32
  ft_sequence, uint32 status, int32 Fx Fy Fz Tx Ty Tz`` in counts).
  ``rdt_sequence`` starts at 1 with every start request; ``ft_sequence``
  counts the device's internal samples at 7000/s since power-on (it goes on
  counting between streams and is decimated with the RDT rate).
* **HTTP** (default port 80): ``GET /netftapi2.xml``, the sensor's active
  configuration (``prodname``, ``cfgcpf``, ``cfgcpt``, ``scfgfu``, ``scfgtu``,
  ``comrdtrate``, ``runrate``, ``runstat``, ``cfgmr``).

The readings are the ``sim`` sensor's (:class:`~hapticlab.plugins.sensors.sim.SimSensor`)
at the internal rate, so the physics and the world's injected faults
(``[[world.faults]]``) are the session's. On top of those, :class:`RdtFault`
injects what a network and a device do wrong on the wire: dropped,
duplicated and reordered records, status bits, a stalled ft_sequence,
saturated counts.

Records are sent in bursts about once a millisecond: every sample whose time
(on the monotonic clock, from the emulator's start) has come goes out, so the
average rate is exact whatever the scheduler does. Run it as
``hapticlab emulate netft --address 127.0.0.x`` (:func:`add_arguments`,
:func:`run`) or from Python::

    with NetFTEmulator(world, address="127.0.0.20", rdt_port=0, http_port=0) as emu:
        ...  # emu.rdt_port, emu.http_port: the ports it got
"""

from __future__ import annotations

import argparse
import math
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from xml.sax.saxutils import escape

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.types import STATUS_SATURATED, EmulatorCommand
from hapticlab.plugins.sensors.netft import (
    ATI_ERROR_SUMMARY,
    ATI_SATURATION,
    FORCE_UNITS,
    FT_RATE_HZ,
    RDT_PORT,
    TORQUE_UNITS,
)
from hapticlab.plugins.sensors.sim import SimSensor
from hapticlab.plugins.serving import serve_until_stopped
from hapticlab.plugins.simworld.physics import SimWorld

REQUEST = struct.Struct(">HHI")
"""An RDT request: header 0x1234, command, sample count."""
RECORD = struct.Struct(">III6i")
"""An RDT record: rdt_sequence, ft_sequence, status, six counts."""
HEADER = 0x1234
CMD_STOP, CMD_START, CMD_BIAS = 0x0000, 0x0002, 0x0042
INT32_MAX = 2**31 - 1
BURST_S = 0.001
"""Records go out in bursts this far apart, s."""
FAULT_KINDS = ("drop", "duplicate", "reorder", "status", "stall", "saturate")


@dataclass(frozen=True, slots=True)
class RdtFault:
    """A fault on the wire, active for records whose world time is in [start, start + duration).

    Attributes:
        kind: ``drop`` (record not sent; its rdt_sequence is used up), ``duplicate``
            (sent twice), ``reorder`` (sent after the next record), ``status`` (``status``
            bits OR-ed into the status word), ``stall`` (the device repeats its last
            ft_sequence and counts: its sampling stalled), ``saturate`` (every axis at its
            saturation counts, status saturation and error summary bits).
        start: world time the fault starts, s.
        duration: how long it lasts, s.
        every: it hits every ``every``-th record while active (1: each one).
        status: the status bits of a ``status`` fault.
    """

    kind: str
    start: float = 0.0
    duration: float = math.inf
    every: int = 1
    status: int = 0

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"kind: unknown fault {self.kind!r}; known: {', '.join(FAULT_KINDS)}")
        if not self.duration > 0 or self.start < 0:
            raise ValueError(f"{self.kind}: start must be >= 0 s and duration > 0 s")
        if self.every < 1:
            raise ValueError(f"{self.kind}: every must be >= 1, got {self.every}")
        if self.kind == "status" and not 0 < self.status <= 0xFFFFFFFF:
            raise ValueError(f"status: bits must be a nonzero 32-bit word, got {self.status!r}")

    def hits(self, t: float, index: int) -> bool:
        """Whether the record at world time ``t`` s (the ``index``-th record sent) is hit."""
        return self.start <= t < self.start + self.duration and index % self.every == 0

    @classmethod
    def parse(cls, text: str) -> "RdtFault":
        """``kind[,start=S][,duration=S][,every=N][,status=0x...]`` (the ``--fault`` syntax)."""
        kind, *fields = [f.strip() for f in text.split(",")]
        values: dict[str, float | int] = {}
        for field in fields:
            key, sep, value = field.partition("=")
            if not sep or key not in ("start", "duration", "every", "status"):
                raise ValueError(f"fault {text!r}: expected key=value with key start, duration, every or status")
            values[key] = int(value, 0) if key in ("every", "status") else float(value)
        return cls(kind, **values)


@dataclass
class EmulatorCounts:
    """What the emulator did on the wire since it started (for tests and the operator).

    Attributes: records ``sent`` (datagrams, duplicates included), ``dropped``,
    ``duplicated``, ``reordered`` (records sent late), ``stalled`` (records repeating the
    last ft_sequence), ``status`` (records with a nonzero status word), ``starts``,
    ``stops`` and ``biases`` (requests obeyed), ``ignored`` (bad requests).
    """

    sent: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    stalled: int = 0
    status: int = 0
    starts: int = 0
    stops: int = 0
    biases: int = 0
    ignored: int = 0


class NetFTEmulator:
    """An emulated Net F/T: RDT over UDP and its XML page over HTTP, on one loopback address.

    Parameters
    ----------
    world : the simulated world the sensor sits in (its physics and faults).
    address : the IPv4 address to serve on (127.0.0.x).
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
        decimation = FT_RATE_HZ / rdt_rate_hz if rdt_rate_hz > 0 else 0.0
        if not (decimation >= 1 and abs(decimation - round(decimation)) < 1e-9):
            raise ValueError(f"rdt_rate_hz: must be {FT_RATE_HZ:g} Hz divided by a whole number, got {rdt_rate_hz!r}")
        if force_unit not in FORCE_UNITS or torque_unit not in TORQUE_UNITS:
            raise ValueError(f"units: force one of {', '.join(FORCE_UNITS)}; torque one of {', '.join(TORQUE_UNITS)}")
        if not (counts_per_force > 0 and counts_per_torque > 0):
            raise ValueError("counts_per_force and counts_per_torque must be > 0")
        self.world = world
        self.address = address
        self.rdt_rate_hz = float(rdt_rate_hz)
        self.decimation = int(round(decimation))
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
        self.counts = EmulatorCounts()
        self.bias_counts = np.zeros(6, dtype=np.int64)
        """(6,) the software bias subtracted from every record, counts (set by a bias request)."""
        self.bias_ft_sequence: int | None = None
        """The ft_sequence of the reading the last bias request took (records after it are biased)."""
        self.client: tuple[str, int] | None = None
        """Where the records go: the address of the last start request."""
        self.t0_ns: int | None = None
        """Monotonic time of internal sample 0 (world time 0), ns."""
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        self._udp.bind((address, rdt_port))
        self._http = ThreadingHTTPServer((address, http_port), _handler(self))
        self._http.daemon_threads = True
        self.rdt_port = self._udp.getsockname()[1]
        self.http_port = self._http.server_address[1]
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._streaming = False
        self._remaining = 0  # records left of a counted start request (0: until stopped)
        self._rdt_sequence = 0
        self._sent_index = 0
        self._held: bytes | None = None  # a record held back by a reorder fault
        self._last: tuple[int, np.ndarray] | None = None  # the last (ft_sequence, counts) sent, for stalls
        self._lock = threading.Lock()
        self._muted = False
        self.muted_ns: list[int | None] = [None, None]

    # ------------------------------------------------------------------ life cycle

    def start(self) -> "NetFTEmulator":
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

    def __enter__(self) -> "NetFTEmulator":
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
    def last_ft_sequence(self) -> int | None:
        """The ft_sequence of the last record sent (None before the first)."""
        return None if self._last is None else self._last[0]

    @property
    def rdt_sequence(self) -> int:
        """The rdt_sequence of the last record sent in the current stream (0 before its first)."""
        return self._rdt_sequence

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
        body = "".join(f"<{k}>{escape(v)}</{k}>" for k, v in fields.items())
        return f'<?xml version="1.0" encoding="ISO-8859-1"?>\n<netft>{body}</netft>\n'.encode("ascii")

    # ------------------------------------------------------------------ RDT

    def _serve_rdt(self) -> None:
        burst_ns = int(BURST_S * 1e9)
        due_ns = self.t0_ns
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
        if header != HEADER or command not in (CMD_START, CMD_STOP, CMD_BIAS):
            self.counts.ignored += 1
            return
        with self._lock:
            if command == CMD_START:
                self.client, self._streaming, self._remaining = sender, True, count
                self._rdt_sequence = 0
                self._held = None
                self.counts.starts += 1
            elif command == CMD_STOP:
                self._streaming = False
                self.counts.stops += 1
            else:
                if self._last is not None:
                    self.bias_counts = self._last[1] + self.bias_counts  # the current unbiased reading
                    self.bias_ft_sequence = self._last[0]
                self.counts.biases += 1

    def _burst(self, now_ns: int) -> None:
        """Sample the world up to now; send the due records if a client is streaming."""
        samples = self._sensor.read(now_ns)  # the device samples whether anyone listens or not
        with self._lock:
            if not self._streaming or self.client is None or self._muted:
                return
            samples = [s for s in samples if s.seq % self.decimation == 0]
            if not samples:
                return
            counts = self.counts_of(np.array([s.force_S for s in samples]), np.array([s.torque_S for s in samples]))
            for sample, raw in zip(samples, counts):
                t = (sample.t_ns - self.t0_ns) / 1e9
                status = ATI_SATURATION | ATI_ERROR_SUMMARY if sample.status & STATUS_SATURATED else 0
                if not (np.isfinite(sample.force_S).all() and np.isfinite(sample.torque_S).all()):
                    status |= ATI_SATURATION | ATI_ERROR_SUMMARY  # the A/D gave no number
                raw = np.clip(raw, -self._saturation_counts, self._saturation_counts)
                self._send(t, (self.ft_sequence_start + sample.seq) % 2**32, status, raw)
                if self._remaining:
                    self._remaining -= 1
                    if self._remaining == 0:
                        self._streaming = False
                        break

    def _send(self, t: float, ft_sequence: int, status: int, raw: np.ndarray) -> None:
        index = self._sent_index
        self._sent_index += 1
        for fault in self.faults:
            if not fault.hits(t, index):
                continue
            if fault.kind == "status":
                status |= fault.status
            elif fault.kind == "saturate":
                raw = np.where(raw < 0, -self._saturation_counts, self._saturation_counts)
                status |= ATI_SATURATION | ATI_ERROR_SUMMARY
            elif fault.kind == "stall" and self._last is not None:
                ft_sequence, raw = self._last[0], self._last[1] + self.bias_counts
                self.counts.stalled += 1
        self._last = (ft_sequence, raw - self.bias_counts)
        self._rdt_sequence = (self._rdt_sequence + 1) % 2**32
        record = RECORD.pack(
            self._rdt_sequence,
            ft_sequence,
            status,
            *np.clip(raw - self.bias_counts, -INT32_MAX - 1, INT32_MAX).tolist(),
        )
        self.counts.status += status != 0
        kinds = {f.kind for f in self.faults if f.kind in ("drop", "duplicate", "reorder") and f.hits(t, index)}
        if "drop" in kinds:
            self.counts.dropped += 1
            return
        if "reorder" in kinds and self._held is None:
            self._held = record  # goes out after the next record
            self.counts.reordered += 1
            return
        self._sendto(record)
        if "duplicate" in kinds:
            self._sendto(record)
            self.counts.duplicated += 1
        if self._held is not None:
            held, self._held = self._held, None
            self._sendto(held)

    def _sendto(self, record: bytes) -> None:
        try:
            self._udp.sendto(record, self.client)
            self.counts.sent += 1
        except OSError:  # the client went away: a real sensor does not care either
            pass


def _handler(emulator: NetFTEmulator) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        """Serves ``/netftapi2.xml``; everything else is 404."""

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            if self.path.split("?")[0] != "/netftapi2.xml":
                self.send_error(404)
                return
            body = emulator.xml()
            self.send_response(200)
            self.send_header("Content-Type", "text/xml")
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Connection", "close")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format, *args) -> None:  # quiet: the operator watches the RDT stream
            pass

    return Handler


# --------------------------------------------------------------------------- command line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``hapticlab emulate netft`` (the host adds ``--session`` and ``--seed``: its world)."""
    parser.add_argument(
        "--address",
        default="127.0.0.1",
        help="IPv4 address to serve on (default 127.0.0.1); a loopback address 127.0.0.x keeps the emulator "
        "on this machine, any other address of this machine (0.0.0.0: all of them) serves the network",
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
        ),
    )
