"""Processes a test starts beside it: ``Popen`` whose every wait times out, naming what it waited for.

Take them through the ``spawn_process`` fixture (tests/conftest.py: the test is then in the realtime tier and
whatever still runs at its end is killed). A module-scoped fixture that must outlive one test calls
:func:`start_child` itself, ends the process in its own ``finally`` and takes ``paced_run`` or another
realtime fixture, so that its tests are in the realtime tier.
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading

import pytest

PROCESS_START_S = 60.0
"""s: how long a process may take to print its first line (its imports, on a loaded machine)."""
PROCESS_STOP_S = 30.0
"""s: how long a process may take to end once asked to, before it is killed."""


class Child(subprocess.Popen):
    """A process started by a test: ``Popen`` with waits that time out, naming the process (``what``).

    Its stdout is read by a thread of its own once a line is asked for (``next_line``): a line already read
    into a buffer is never waited for again, and ``finish`` returns what came after.
    """

    what = "the process"
    _lines: queue.Queue | None = None
    _reader: threading.Thread | None = None

    def next_line(self, timeout: float = PROCESS_START_S) -> str:
        """The next line it prints on stdout (its address, its port, "ready"); fails naming it after ``timeout``."""
        if self._lines is None:
            self._lines = queue.Queue()
            self._reader = threading.Thread(target=self._read_lines, name=f"stdout of {self.what}", daemon=True)
            self._reader.start()
        try:
            line = self._lines.get(timeout=timeout)
        except queue.Empty:
            pytest.fail(f"{self.what} printed no line within {timeout:g} s")
        if line is None:
            self.wait()
            err = self.stderr.read() if self.stderr is not None else ""
            pytest.fail(f"{self.what} ended ({self.returncode}) before printing a line: {err!r}")
        return line

    first_line = next_line

    def _read_lines(self) -> None:
        for line in self.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def finish(self, signum: int = signal.SIGTERM, timeout: float = PROCESS_STOP_S):
        """Send ``signum`` if it still runs, then return what it printed on stdout after the lines read; killed,
        and failing, after ``timeout``."""
        if self.poll() is None:
            self.send_signal(signum)
        if self._reader is None:
            try:
                out, _ = self.communicate(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.kill()
                self.communicate()
                pytest.fail(f"{self.what} did not end within {timeout:g} s of {signal.Signals(signum).name}")
            return out
        try:
            self.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            self.wait()
            pytest.fail(f"{self.what} did not end within {timeout:g} s of {signal.Signals(signum).name}")
        self._reader.join(timeout)
        rest = []
        while not self._lines.empty():
            line = self._lines.get()
            if line is not None:
                rest.append(line)
        return "".join(rest)

    def wait_for_exit(self, timeout: float = PROCESS_STOP_S) -> int:
        """Its exit code once it ends on its own; fails after ``timeout``."""
        try:
            return self.wait(timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{self.what} did not end within {timeout:g} s")

    def close_pipes(self) -> None:
        """Kill it if it still runs, reap it, close its pipes."""
        if self.poll() is None:
            self.kill()
            self.wait()
        if self._reader is not None:
            self._reader.join(PROCESS_STOP_S)
        for stream in (self.stdin, self.stdout, self.stderr):
            if stream is not None:
                stream.close()


def _default_sigint() -> None:
    """In the child: Ctrl-C is KeyboardInterrupt again (a runner started in the background ignores SIGINT, an
    ignored signal stays ignored across exec, and Python then installs no handler for it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_child(args, what: str, **kwargs) -> Child:
    """Start ``args`` as a :class:`Child` named ``what`` (stdout and stderr piped, as text, unless given)."""
    kwargs.setdefault("stdout", subprocess.PIPE)
    kwargs.setdefault("stderr", subprocess.PIPE)
    kwargs.setdefault("text", True)
    child = Child(args, preexec_fn=_default_sigint, **kwargs)
    child.what = what
    return child


def hapticlab_command(*args: str) -> list[str]:
    """``hapticlab ARGS`` as this interpreter runs it (the installed script may be another venv's)."""
    return [sys.executable, "-c", "import sys; from hapticlab.sessions.cli import main; sys.exit(main())", *args]
