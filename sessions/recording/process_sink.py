"""The parent's side of the recording's writer process: a :class:`~.sinks.McapSink` in a child, fed over a pipe.

:class:`ProcessSink` starts :mod:`.sinks` as a script in a child process and
hands it each hand-over's messages as one pickled batch of already encoded
bytes (one pipe write), so the writing and the chunks' compression run on the
other core. The loop keeps encoding (CDR, JSON) on its own side, so a bad
message still raises where it was written. A full pipe blocks the loop
(back-pressure): nothing is ever dropped. The child finishes the file if this
process dies (:mod:`.sinks`).
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

from hapticlab.sessions.recording import sinks
from hapticlab.sessions.recording.sinks import LENGTH, LIVE_ADDRESS, READY

PIPE_BYTES = 1 << 20
"""Pipe buffer asked for (Linux ``F_SETPIPE_SZ``), bytes: about a second of a 7 kHz session's messages, so the
loop rides out the child's pauses."""


class WriterProcessError(RuntimeError):
    """The recording's writer process failed or exited; the message says how."""


class ProcessSink:
    """A :class:`McapSink` in a child process, fed one pickled batch per :meth:`send`.

    ``path`` must exist (the Recorder creates it, so an existing recording is
    refused in the caller's process); the child truncates and writes it. The
    constructor returns once the child is ready to write.
    """

    def __init__(self, path: Path, library: str, flush_interval_s: float, chunk_size: int, live: str = ""):
        self.path = path
        self.live_address = ""
        """Where the live view listens ("HOST:PORT"), "" without one."""
        self._ops: list[tuple] = []
        self._proc = subprocess.Popen(
            # sinks.py run as a script: it needs mcap only, not hapticlab's packages (it starts several times faster)
            [
                sys.executable,
                "-c",
                _RUN_THIS_FILE,
                sinks.__file__,
                os.fspath(path),
                library,
                repr(float(flush_interval_s)),
                str(int(chunk_size)),
                live,
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=_child_env(),
            start_new_session=False,
        )
        assert self._proc.stdin is not None and self._proc.stdout is not None  # stdin=PIPE, stdout=PIPE
        self._stdin, self._stdout = self._proc.stdin, self._proc.stdout
        self._pipe = self._stdin.fileno()
        try:
            import fcntl

            fcntl.fcntl(self._pipe, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        except (ImportError, AttributeError, OSError):  # not Linux, or above pipe-max-size: the default 64 KiB
            pass
        line = self._stdout.readline()
        if live and line.startswith(LIVE_ADDRESS):  # the live view's address, then ready
            self.live_address = line[len(LIVE_ADDRESS) :].decode().strip()
            line = self._stdout.readline()
        if line != READY:
            self._proc.wait()
            raise WriterProcessError(
                f"recording writer process for {path} did not start "
                f"(exit status {self._proc.returncode}): {line.decode(errors='replace').strip()}"
            )

    @property
    def pid(self) -> int:
        """The writer process's pid."""
        return self._proc.pid

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self._ops.append(("metadata", name, values))

    def register_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        self._ops.append(("schema", schema_id, name, encoding, data))

    def register_channel(self, channel_id: int, topic: str, message_encoding: str, schema_id: int) -> None:
        self._ops.append(("channel", channel_id, topic, message_encoding, schema_id))

    def add_message(self, channel_id: int, t_ns: int, data: bytes, seq: int) -> None:
        self._ops.append((channel_id, t_ns, data, seq))

    def send(self) -> None:
        """Hand the messages written since the last send to the writer process (one pipe write)."""
        if not self._ops:
            return
        batch = pickle.dumps(self._ops, protocol=pickle.HIGHEST_PROTOCOL)
        self._ops = []
        self._write(LENGTH.pack(len(batch)) + batch)

    def flush(self) -> None:
        self._ops.append(("flush",))
        self.send()

    def finish(self) -> None:
        """Send what is left, let the child finish the file, wait for it; raise if it failed."""
        self._ops.append(("finish",))
        try:
            self.send()
        finally:
            self._stdin.close()
            reply = self._stdout.read()
            self._stdout.close()
            status = self._proc.wait()
        if status != 0 or not reply.startswith(b"finished"):
            raise WriterProcessError(
                f"recording writer process for {self.path} failed (exit status {status}): "
                f"{reply.decode(errors='replace').strip() or 'no reply'}"
            )

    def abort(self) -> None:
        """Stop the child without a footer (a failed start)."""
        self._proc.kill()
        self._proc.wait()
        self._stdin.close()
        self._stdout.close()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._pipe, view) :]
        except BrokenPipeError:
            status = self._proc.wait()
            raise WriterProcessError(
                f"recording writer process for {self.path} exited (status {status}); the file holds what it had written"
            ) from None


_RUN_THIS_FILE = "import runpy, sys; runpy.run_path(sys.argv[1], run_name='__main__')"


def _child_env() -> dict[str, str]:
    """The environment with this interpreter's import path, so the child imports the same hapticlab."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    return env
