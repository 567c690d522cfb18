"""A UR controller's RTDE port (30004) for the emulated arm: connections, recipes, inputs and text messages.

:class:`RTDEServer` speaks the wire of ``rtde_protocol.py`` to every client
connected: it answers the version requests, keeps each client's output and
input recipes (an input field belongs to the first client whose recipe writes
it), keeps the input values written and the text messages sent, and at each
controller cycle sends the data packages due (:meth:`RTDEServer.serve_cycle`)
with the outputs the controller (``ur_emulator.UREmulator``) computes for that
cycle. Every client has a thread of its own; the server never blocks the
controller's cycle on a slow client beyond its socket's send.
"""

from __future__ import annotations

import contextlib
import select
import socket
import struct
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hapticlab.plugins.kinematics.rtde_protocol import (
    DATA_PACKAGE,
    ERROR,
    GET_URCONTROL_VERSION,
    HEADER,
    INPUT_TYPES,
    OUTPUT_TYPES,
    PAUSE,
    PROTOCOL_VERSION,
    REQUEST_PROTOCOL_VERSION,
    SETUP_INPUTS,
    SETUP_OUTPUTS,
    START,
    TEXT_MESSAGE,
    TYPE_FORMATS,
    names,
    pack_text_message,
    package,
    unpack_text_message,
    width,
    zero,
)


@dataclass
class _OutputRecipe:
    recipe_id: int
    names: list[str]
    packer: struct.Struct
    every: float
    """Controller cycles per package (cycle rate / frequency)."""
    next_cycle: float = 0.0


@dataclass
class _Client:
    sock: socket.socket
    peer: str
    outputs: dict[int, _OutputRecipe] = field(default_factory=dict)
    inputs: dict[int, tuple[list[str], struct.Struct]] = field(default_factory=dict)
    streaming: bool = False
    protocol: int = 1
    send_lock: threading.Lock = field(default_factory=threading.Lock)

    def send(self, data: bytes) -> bool:
        """Send a whole package; False when the client has gone."""
        try:
            with self.send_lock:
                self.sock.sendall(data)
            return True
        except OSError:
            return False


class RTDEServer:
    """The RTDE port of one emulated controller.

    Parameters
    ----------
    address, port : where to listen (port 0 picks a free one: :attr:`port` after :meth:`listen`).
    cycle_hz : the controller's cycle rate, Hz: the fastest output frequency it accepts.
    controller_version : (major, minor, bugfix, build) answered to ``v``.
    current_cycle : the controller's cycle now (a client's ``S`` starts its packages there).
    """

    def __init__(
        self,
        address: str,
        port: int,
        cycle_hz: float,
        controller_version: tuple[int, int, int, int],
        current_cycle: Callable[[], int],
    ):
        self.address, self.port = address, port
        self.cycle_hz = cycle_hz
        self.controller_version = controller_version
        self._current_cycle = current_cycle
        self.messages: list[str] = []
        """Text messages clients sent, oldest first."""
        self.packages_sent = 0
        """Data packages sent to clients since start."""
        self._inputs: dict[str, Any] = {}
        self._input_owner: dict[str, _Client] = {}
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._socket: socket.socket | None = None

    @property
    def listening(self) -> bool:
        """Whether :meth:`listen` was called and :meth:`close` not since."""
        return self._socket is not None

    def listen(self) -> None:
        """Bind and listen; accept clients on a thread of its own (OSError when the address cannot be served)."""
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((self.address, self.port))
        server.listen(8)
        server.settimeout(0.1)  # the accept loop looks at the stop flag this often
        self.port = server.getsockname()[1]
        self._socket = server
        self._stop.clear()
        self._thread = threading.Thread(target=self._accept_loop, name="ur-emulator _accept_loop", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Close every connection and the listening socket (a client sees the controller gone)."""
        self._stop.set()
        if self._socket is not None:
            self._socket.close()
            self._socket = None
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            _close(client.sock)
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def inputs(self) -> dict[str, Any]:
        """The input fields clients have written (register name → last value)."""
        with self._lock:
            return dict(self._inputs)

    @property
    def clients(self) -> int:
        """Clients connected now."""
        with self._lock:
            return len(self._clients)

    def broadcast(self, data: bytes) -> None:
        """Send a package (e.g. a text message) to every client connected."""
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            client.send(data)

    def serve_cycle(self, cycle: int, outputs: Callable[[int], dict[str, Any]], stalled: bool = False) -> int:
        """Send the data packages due at ``cycle``, their fields from ``outputs(cycle)`` (called only when a
        package is due), the input registers read back, and every other output 0. ``stalled``: none is sent,
        and the stream goes on at the next due cycle. Returns the packages not sent (stalled)."""
        with self._lock:
            due = [
                (client, recipe)
                for client in self._clients
                if client.streaming
                for recipe in client.outputs.values()
                if recipe.next_cycle <= cycle
            ]
            inputs = dict(self._inputs)
        if not due:
            return 0
        if stalled:
            for _client, recipe in due:
                recipe.next_cycle += recipe.every
            return len(due)
        values = outputs(cycle)
        for client, recipe in due:
            recipe.next_cycle += recipe.every
            row: list[Any] = []
            for name in recipe.names:
                value = values[name] if name in values else inputs.get(name, zero(OUTPUT_TYPES[name]))
                row.extend(value if isinstance(value, tuple) else (value,))
            if client.send(package(DATA_PACKAGE, bytes([recipe.recipe_id]) + recipe.packer.pack(*row))):
                self.packages_sent += 1
        return 0

    # ------------------------------------------------------------------ the protocol

    def _accept_loop(self) -> None:
        server = self._socket
        while not self._stop.is_set():
            try:
                sock, peer = server.accept()  # type: ignore[union-attr]  # open() set it before starting this thread
            except TimeoutError:
                continue
            except OSError:
                return
            sock.setblocking(True)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            client = _Client(sock, f"{peer[0]}:{peer[1]}")
            with self._lock:
                self._clients.append(client)
            threading.Thread(
                target=self._client_loop, args=(client,), name=f"ur-emulator {client.peer}", daemon=True
            ).start()

    def _client_loop(self, client: _Client) -> None:
        buffer = b""
        try:
            while not self._stop.is_set():
                readable, _, _ = select.select([client.sock], [], [], 0.1)
                if not readable:
                    continue
                chunk = client.sock.recv(65536)
                if not chunk:
                    break
                buffer += chunk
                while len(buffer) >= HEADER.size:
                    size, kind = HEADER.unpack_from(buffer)
                    if size < HEADER.size:  # not RTDE: drop the connection
                        return
                    if len(buffer) < size:
                        break
                    payload, buffer = buffer[HEADER.size : size], buffer[size:]
                    self._handle(client, kind, payload)
        except (OSError, ValueError):
            pass
        finally:
            with self._lock:
                if client in self._clients:
                    self._clients.remove(client)
                for name in [n for n, owner in self._input_owner.items() if owner is client]:
                    del self._input_owner[name]
            _close(client.sock)

    def _handle(self, client: _Client, kind: int, payload: bytes) -> None:
        if kind == REQUEST_PROTOCOL_VERSION:
            (version,) = struct.unpack(">H", payload[:2])
            accepted = version == PROTOCOL_VERSION
            if accepted:
                client.protocol = version
            client.send(package(kind, bytes([accepted])))
        elif kind == GET_URCONTROL_VERSION:
            client.send(package(kind, struct.pack(">IIII", *self.controller_version)))
        elif kind == TEXT_MESSAGE:
            self.messages.append(unpack_text_message(payload))
        elif kind == SETUP_OUTPUTS:
            client.send(package(kind, self._setup_outputs(client, payload)))
        elif kind == SETUP_INPUTS:
            client.send(package(kind, self._setup_inputs(client, payload)))
        elif kind == START:
            with self._lock:
                cycle = self._current_cycle()
                for recipe in client.outputs.values():
                    recipe.next_cycle = float(cycle)
                client.streaming = True
            client.send(package(kind, b"\x01"))
        elif kind == PAUSE:
            client.streaming = False
            client.send(package(kind, b"\x01"))
        elif kind == DATA_PACKAGE:
            input_recipe = client.inputs.get(payload[0]) if payload else None
            if input_recipe is None:
                client.send(
                    pack_text_message(f"data package for unknown input recipe {payload[:1].hex()}", level=ERROR)
                )
                return
            fields, packer = input_recipe
            flat = list(packer.unpack(payload[1 : 1 + packer.size]))
            with self._lock:
                for name in fields:
                    n = width(INPUT_TYPES[name])
                    value, flat = (tuple(flat[:n]) if n > 1 else flat[0]), flat[n:]
                    self._inputs[name] = value
        else:
            client.send(pack_text_message(f"unknown package type {kind}", level=ERROR))

    def _setup_outputs(self, client: _Client, payload: bytes) -> bytes:
        (frequency,) = struct.unpack(">d", payload[:8])
        fields = names(payload[8:])
        types = [OUTPUT_TYPES.get(name, "NOT_FOUND") for name in fields]
        ok = bool(fields) and "NOT_FOUND" not in types
        if not 0 < frequency <= self.cycle_hz:
            ok = False
            client.send(
                pack_text_message(
                    f"output frequency {frequency:g} Hz: must be within (0, {self.cycle_hz:g}] on this controller",
                    level=ERROR,
                )
            )
        recipe_id = 0
        if ok:
            with self._lock:
                recipe_id = len(client.outputs) + 1
                packer = struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types))
                client.outputs[recipe_id] = _OutputRecipe(recipe_id, fields, packer, self.cycle_hz / frequency)
        return bytes([recipe_id]) + ",".join(types).encode()

    def _setup_inputs(self, client: _Client, payload: bytes) -> bytes:
        fields = names(payload)
        with self._lock:
            types = [INPUT_TYPES.get(name, "NOT_FOUND") for name in fields]
            types = [
                "IN_USE" if t != "NOT_FOUND" and self._input_owner.get(n, client) is not client else t
                for n, t in zip(fields, types)
            ]
            recipe_id = 0
            if fields and not {"NOT_FOUND", "IN_USE"} & set(types):
                recipe_id = len(client.inputs) + 1
                client.inputs[recipe_id] = (fields, struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in types)))
                for name in fields:
                    self._input_owner[name] = client
        return bytes([recipe_id]) + ",".join(types).encode()


def _close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()
