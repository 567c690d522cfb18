"""The emulators' shared wait: it ends on SIGTERM whichever thread the kernel hands the signal to."""

import signal
import threading
import time

from hapticlab.plugins.serving import serve_until_stopped

GUARD_S = 5.0  # the wait's own limit: reaching it means the SIGTERM was slept through


def test_a_sigterm_delivered_to_a_serving_thread_still_ends_the_wait():
    sleeper = threading.Thread(target=time.sleep, args=(GUARD_S + 1.0,), daemon=True)
    sleeper.start()
    stop = threading.Event()
    previous = signal.getsignal(signal.SIGTERM)

    def ready():  # as the emulator's reader thread would: the signal lands on it, not on the main thread
        threading.Timer(0.05, signal.pthread_kill, args=(sleeper.ident, signal.SIGTERM)).start()

    t0 = time.monotonic()
    serve_until_stopped(GUARD_S, stop, ready)
    assert time.monotonic() - t0 < 1.0
    assert stop.is_set()  # the emulator's own threads end with it
    assert signal.getsignal(signal.SIGTERM) is previous


def test_the_duration_ends_the_wait_and_sets_stop():
    stop = threading.Event()
    t0 = time.monotonic()
    serve_until_stopped(0.25, stop)
    assert 0.25 <= time.monotonic() - t0 < 1.0
    assert stop.is_set()
