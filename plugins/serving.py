"""What every emulator's command shares: serve until Ctrl-C, SIGTERM or ``--duration``."""

from __future__ import annotations

import signal
import threading


def serve_until_stopped(duration_s: float | None, stop: threading.Event | None = None) -> None:
    """Block until Ctrl-C, SIGTERM, ``stop`` is set or ``duration_s`` (s; None: no limit) has passed.

    SIGTERM sets ``stop`` for the while (only the main thread can install a
    handler); the previous handler is back on return, and ``stop`` is set, so
    the emulator's own threads (e.g. scheduled faults) end with it.
    """
    stop = stop if stop is not None else threading.Event()
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: stop.set()) if main else None
    try:
        stop.wait(duration_s)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
