"""What every emulator's command shares: serve until Ctrl-C, SIGTERM or ``--duration``."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

WAKE_S = 0.1
"""Longest the main thread sleeps before it runs a signal handler another thread received (s)."""


def serve_until_stopped(
    duration_s: float | None, stop: threading.Event | None = None, ready: Callable[[], None] | None = None
) -> None:
    """Block until Ctrl-C, SIGTERM, ``stop`` is set or ``duration_s`` (s; None: no limit) has passed.

    SIGTERM ends the wait for the while (only the main thread can install a
    handler); the previous handler is back on return, and ``stop`` is set, so
    the emulator's own threads (e.g. scheduled faults) end with it. ``ready``
    (what the emulator prints to say it serves: its port, its address) runs
    once the handler is in place, so a SIGTERM sent as soon as it is read ends
    the emulator cleanly, never by the default handler.

    The wait is sliced (``WAKE_S``): the kernel may deliver SIGTERM to any of
    the process's threads, and when it lands on a serving thread the Python
    handler only runs once the main thread wakes; an ``Event.wait`` with no
    timeout would then sleep through it (a CI run hung 10 s on exactly that).
    """
    stop = stop if stop is not None else threading.Event()
    main = threading.current_thread() is threading.main_thread()
    terminated: list[int] = []  # the handler only appends: an Event.set there could deadlock on the
    # Event's own lock if the signal lands while this thread holds it inside stop.wait
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: terminated.append(signum)) if main else None
    try:
        if ready is not None:
            ready()
        deadline = None if duration_s is None else time.monotonic() + duration_s
        while not stop.is_set() and not terminated:
            left = WAKE_S if deadline is None else min(WAKE_S, deadline - time.monotonic())
            if left <= 0.0:
                break
            stop.wait(left)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def serve_on_pty(
    emulator: Any, duration_s: float | None, banner: Callable[[], str], faults: Sequence[Any] = ()
) -> None:
    """Serve a pseudo-terminal ``emulator`` (``pty_emulator.PtyEmulator``: started here, stopped on return) until
    Ctrl-C, SIGTERM or ``duration_s``. Prints its port first (the line a script reads), then ``banner()``, then
    injects each of ``faults`` (``scheduled_fault.ScheduledFault``) from a thread of its own."""
    stop = threading.Event()

    def ready() -> None:
        print(emulator.port, flush=True)
        print(banner(), flush=True)
        for fault in faults:
            threading.Thread(target=fault.inject, args=(emulator, stop), daemon=True).start()

    with emulator:
        serve_until_stopped(duration_s, stop, ready)
