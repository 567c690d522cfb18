"""A paced loop's thread at a real-time priority (``SCHED_FIFO``) while it ticks, and back afterwards.

A control loop waits in ``time.sleep`` until its next tick is due; under the
ordinary policy (``SCHED_OTHER``) the kernel wakes it when it gets to it, and
on a loaded or virtualised machine that is sometimes more than a period late:
the loop skips a tick (an ``overrun`` event). ``SCHED_FIFO`` wakes it first,
as ros2_control and the dVRK's console do for theirs (what it changed on this
project's paced sessions: docs/safety.md).

Only the loop's thread changes (Linux schedules threads, and ``pid = 0`` is the
calling one); the devices' threads and the recording's writer process (started
before, and ``SCHED_BATCH`` by its own choice) keep theirs. Asking needs
``CAP_SYS_NICE`` or an ``rtprio`` limit (``/etc/security/limits.conf``); without
either the session runs at the ordinary policy and says why.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def fifo_priority(priority: int) -> Iterator[str]:
    """Run the body with the calling thread at ``SCHED_FIFO`` ``priority`` (1-99; 0: leave it as it is).

    Yields "" when the priority was set (or none was asked for), else why it could not be (the body runs
    anyway, at the thread's own policy). The thread's policy and priority before are restored afterwards.
    """
    if priority <= 0:
        yield ""
        return
    if not hasattr(os, "sched_setscheduler"):
        yield "SCHED_FIFO is not available on this system"
        return
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        yield (
            f"SCHED_FIFO priority {priority} refused ({exc.strerror or exc}): give the user CAP_SYS_NICE or "
            f"an rtprio limit of {priority} (limits.conf), or set session.realtime_priority = 0"
        )
        return
    try:
        yield ""
    finally:
        os.sched_setscheduler(0, *before)
