"""Where a :class:`~.writer.Recorder`'s encoded messages go: an MCAP writer on the file, here or in the writer process.

:class:`McapSink` holds the ``mcap`` writer and the file: zstd chunks, the chunk
in progress finished and flushed to the OS about once a second. ``mcap``'s
writer is pure Python and a finished chunk's compression takes a fraction of a
millisecond, which a 1 kHz loop cannot pay on its own thread: a live session
runs its McapSink in a child process (:class:`~.process_sink.ProcessSink`, the
parent's side), this file run as a script (:func:`serve`; it imports ``mcap``
only, so the child starts fast). The child:

- writes the same file a :class:`McapSink` would, and flushes about once a
  second whether batches come or not (so a crash of both loses at most the
  last second, and :func:`~.recover.recover` salvages the rest);
- finishes the file (footer, summary, index) when the parent closes it, *and*
  when the parent dies without closing (end of file on the pipe: SIGKILL,
  a crash), so a killed session's recording is complete up to its last tick;
- ignores SIGINT, SIGTERM and SIGHUP: Ctrl-C in a terminal reaches the whole
  process group, and the parent ends the session (and the file) itself.

**Live view** (``live="HOST:PORT"``): the child also serves every message it
writes over Foxglove's WebSocket protocol (:class:`FoxgloveTee`, the
``foxglove-sdk`` extra), the same topics, schemas and bytes as the file, so an
instructor watches the session in Foxglove while it runs. It costs the loop
nothing: the messages are already in the writer process.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import select
import signal
import struct
import sys
import time
from typing import IO, TYPE_CHECKING, Protocol

from mcap.writer import CompressionType, Writer

if TYPE_CHECKING:
    from foxglove import Channel

_monotonic = time.monotonic
LENGTH = struct.Struct("<I")
"""The length prefix of each batch on the pipe (bytes, little-endian)."""
READY = b"ready\n"
LIVE_ADDRESS = b"live-address "
"""The child's first line when it serves a live view: this, then where (``HOST:PORT``)."""


class Sink(Protocol):
    """What a Recorder needs from where its bytes go (ids are chosen by the Recorder)."""

    def add_metadata(self, name: str, values: dict[str, str]) -> None: ...
    def register_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None: ...
    def register_channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None: ...
    def add_message(self, channel_id: int, t_ns: int, data: bytes, seq: int) -> None: ...
    def send(self) -> None: ...
    def flush(self) -> None: ...
    def finish(self) -> None: ...
    def abort(self) -> None: ...


class McapSink:
    """An ``mcap`` writer on ``file``: zstd chunks, flushed to the OS every ``flush_interval_s`` (s)."""

    def __init__(self, file: IO[bytes], library: str, flush_interval_s: float, chunk_size: int):
        self._file = file
        self._writer = Writer(file, chunk_size=int(chunk_size), compression=CompressionType.ZSTD)
        self._writer.start(profile="", library=library)
        self._schemas: dict[int, int] = {}  # the Recorder's id -> the writer's
        self._channels: dict[int, int] = {}
        self.flush_interval_s = float(flush_interval_s)
        self.next_flush = _monotonic() + self.flush_interval_s
        self.messages = 0

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self._writer.add_metadata(name, values)

    def register_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        self._schemas[schema_id] = self._writer.register_schema(name=name, encoding=encoding, data=data)

    def register_channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        self._channels[channel_id] = self._writer.register_channel(
            topic=topic, message_encoding=message_encoding, schema_id=self._schemas[schema_id]
        )

    def add_message(self, channel_id: int, t_ns: int, data: bytes, seq: int) -> None:
        self._writer.add_message(self._channels[channel_id], t_ns, data, t_ns, seq)
        self.messages += 1
        now = _monotonic()
        if now >= self.next_flush:
            self.flush(now)

    def send(self) -> None:
        """Nothing to hand over: every message is in the writer already."""

    def flush(self, now: float | None = None) -> None:
        """Finish the chunk in progress and hand it to the OS."""
        self._writer.flush()
        self._file.flush()
        self.next_flush = (_monotonic() if now is None else now) + self.flush_interval_s

    def finish(self) -> None:
        """Write the footer (summary, index) and close the file."""
        try:
            self._writer.finish()
            self._file.flush()
        finally:
            self._file.close()

    def abort(self) -> None:
        """Close the file as it is (a failed start)."""
        self._file.close()


class FoxgloveTee:
    """Serves the recording's messages live over Foxglove's WebSocket protocol (``foxglove-sdk``).

    Args:
        address: ``"HOST:PORT"`` to listen on (loopback by default: ``127.0.0.1:8765``).

    Each channel the recording registers becomes a Foxglove channel with the same
    topic, schema and message encoding (JSON schema with JSON, ``ros2msg`` with CDR),
    and each message is logged with its recording time as the log time.
    """

    def __init__(self, address: str):
        import foxglove

        host, _, port = address.rpartition(":")
        self._foxglove = foxglove
        self.server = foxglove.start_server(name="hapticlab", host=host or "127.0.0.1", port=int(port))
        self.port = self.server.port
        self._schemas: dict[int, tuple[str, str, bytes]] = {}
        self._channels: dict[int, Channel] = {}

    def register_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        self._schemas[schema_id] = (name, encoding, data)

    def register_channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        name, encoding, data = self._schemas[schema_id]
        self._channels[channel_id] = self._foxglove.Channel(
            topic,
            schema=self._foxglove.Schema(name=name, encoding=encoding, data=data),
            message_encoding=message_encoding,
        )

    def add_message(self, channel_id: int, t_ns: int, data: bytes) -> None:
        self._channels[channel_id].log(data, log_time=t_ns)

    def stop(self) -> None:
        self.server.stop()


def serve(
    path: str,
    library: str,
    flush_interval_s: float,
    chunk_size: int,
    source: IO[bytes],
    reply: IO[bytes],
    live: str = "",
) -> None:
    """Write batches read from ``source`` to ``path`` until ``finish`` or end of file; report on ``reply``.

    With ``live`` ("HOST:PORT") every message also goes to a Foxglove WebSocket server there.
    """
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):  # the parent ends the session; end of file ends us
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    tee = None
    if live:  # first, so a live view that cannot start leaves the file as the parent created it (empty)
        try:
            tee = FoxgloveTee(live)
        except Exception as exc:  # no foxglove-sdk, or the address is taken: one line to the parent
            reply.write(f"live view on {live}: {type(exc).__name__}: {exc}\n".encode())
            reply.flush()
            return
    file = open(path, "r+b")  # noqa: SIM115 - the sink's finish() closes it
    file.truncate(0)
    sink = McapSink(file, library, flush_interval_s, chunk_size)
    if tee is not None:
        reply.write(LIVE_ADDRESS + f"{live.rpartition(':')[0] or '127.0.0.1'}:{tee.port}\n".encode())
    reply.write(READY)
    reply.flush()
    fd = source.fileno()
    reader = _Batches(fd)
    finished = False
    while not finished:
        wait = max(0.0, sink.next_flush - _monotonic())
        if not select.select([fd], [], [], wait)[0]:
            sink.flush()  # a quiet parent: still at most a second in memory
            continue
        batches = reader.read()
        if batches is None:  # the parent died without closing: finish what we have
            break
        for batch in batches:
            for op in pickle.loads(batch):
                kind = op[0]
                if type(kind) is int:
                    sink.add_message(*op)
                    if tee is not None:
                        tee.add_message(*op[:3])
                elif kind == "metadata":
                    sink.add_metadata(op[1], op[2])
                elif kind == "schema":
                    sink.register_schema(*op[1:])
                    if tee is not None:
                        tee.register_schema(*op[1:])
                elif kind == "channel":
                    sink.register_channel(*op[1:])
                    if tee is not None:
                        tee.register_channel(*op[1:])
                elif kind == "flush":
                    sink.flush()
                elif kind == "finish":
                    finished = True
                else:
                    raise ValueError(f"unknown operation {kind!r} from the recorder")
    sink.finish()
    if tee is not None:
        tee.stop()
    try:
        reply.write(b"finished %d messages\n" % sink.messages)
        reply.flush()
    except BrokenPipeError:  # the session is gone (killed, or it raised): the file is finished all the same
        pass


class _Batches:
    """Length-prefixed batches from a pipe, read as they come."""

    def __init__(self, fd: int):
        self.fd = fd
        self.buffer = bytearray()

    def read(self) -> list[bytes] | None:
        """The complete batches now available (perhaps none); None at end of file."""
        chunk = os.read(self.fd, 1 << 20)
        if not chunk:
            return None
        self.buffer += chunk
        out = []
        while len(self.buffer) >= 4:
            (n,) = LENGTH.unpack_from(self.buffer)
            if len(self.buffer) < 4 + n:
                break
            out.append(bytes(self.buffer[4 : 4 + n]))
            del self.buffer[: 4 + n]
        return out


def _yield_to_the_loop() -> None:
    """Make this process one that never pre-empts the session's loop when it wakes (Linux ``SCHED_BATCH``).

    Each hand-over wakes the writer; woken as an ordinary process, the scheduler often runs it at once on
    the loop's own core, and the loop waits for its core back (docs/safety.md, "Overruns"). A batch process
    is not run ahead of the process it woke; it still gets the other core (or its share of a busy one), so
    it keeps up all the same. Nothing to do where the policy is unknown.
    """
    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))


def _main(argv: list[str]) -> int:
    _this_file, path, library, flush_interval_s, chunk_size, live = argv
    _yield_to_the_loop()
    serve(path, library, float(flush_interval_s), int(chunk_size), sys.stdin.buffer, sys.stdout.buffer, live)
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
