"""What every emulator's command shares: serve until Ctrl-C, SIGTERM or ``--duration``."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable


def serve_until_stopped(duration_s: float | None, stop: threading.Event | None = None,
                        ready: Callable[[], None] | None = None) -> None:
    """Block until Ctrl-C, SIGTERM, ``stop`` is set or ``duration_s`` (s; None: no limit) has passed.

    SIGTERM sets ``stop`` for the while (only the main thread can install a
    handler); the previous handler is back on return, and ``stop`` is set, so
    the emulator's own threads (e.g. scheduled faults) end with it. ``ready``
    (what the emulator prints to say it serves: its port, its address) runs
    once the handler is in place, so a SIGTERM sent as soon as it is read ends
    the emulator cleanly, never by the default handler.
    """
    stop = stop if stop is not None else threading.Event()
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: stop.set()) if main else None
    try:
        if ready is not None:
            ready()
        stop.wait(duration_s)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
