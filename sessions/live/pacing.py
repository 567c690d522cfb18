"""A paced loop's clock: when each tick is due, the devices' work ahead in its spare time, overruns reported.

With ``realtime = true`` "now" is the monotonic wall clock and ticks are due
every period from the start. A tick that ends early first lets the devices that
can (``PreparesAhead``) do the next ticks' work, then sleeps; a loop that falls
more than one period behind skips the ticks it missed and records an
``overrun`` event saying how far behind it was (at most one such event a
second, counting the ticks skipped in between). With ``realtime = false``
(simulated devices as fast as the machine allows) "now" is the tick's own time.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from typing import Any

from hapticlab.core.types import Event
from hapticlab.sessions.live.status import SessionStatus

PREPARE_AHEAD_TICKS = 10
"""A paced loop asks the devices that prepare ahead (``PreparesAhead``) for the next 10 ticks' samples, each
only while at least half a period is left before the next tick: a device's chunk of work then waits for an
idle moment, and there are ten of them before its samples are read. Asked for the next tick alone, a device
ran after a slow tick too and made the next one late (docs/safety.md, "Overruns")."""
OVERRUN_EVENT_INTERVAL_NS = 1_000_000_000
"""At most one ``overrun`` event a second; the ticks skipped in between are counted in it."""


def freeze_the_heap() -> None:
    """Collect once, then keep everything built so far out of the collector's full passes (``gc.freeze``).

    A paced session's heap is mostly what was built before its first tick (numpy, scipy, numba, the
    plugins); a full (generation 2) collection would walk all of it in one tick and skip many ticks.
    Frozen, a full pass sees only what the session made since. The session's end unfreezes
    (``gc.unfreeze``).
    """
    gc.collect()
    gc.freeze()


class Pacer:
    """When each tick is due and how late the loop runs (built by the loop; :meth:`start` at its first tick).

    Attributes:
        overruns: how often the loop fell more than one period behind (realtime only).
    """

    def __init__(
        self,
        period_ns: int,
        realtime: bool,
        loop_rate_hz: float,
        preparing: list[tuple[str, Any]],
        call: Callable[..., Any],
        on_event: Callable[[Event], None],
        status: SessionStatus,
    ):
        """``preparing``: ``(part, device)`` of the devices that prepare ahead; ``call(part, method, *args)``
        calls a device (what it raises ends the session, named); ``on_event`` records an event; ``status``
        gets how far behind the loop is."""
        self.period_ns, self.realtime, self.loop_rate_hz = period_ns, realtime, loop_rate_hz
        self.preparing, self.call, self.on_event, self.status = preparing, call, on_event, status
        self.t0_ns = 0
        self.overruns = self.skipped_since_event = 0
        self.behind_max_ns = 0
        self.next_overrun_event_ns = 0

    def start(self, t0_ns: int) -> None:
        """Tick ``k`` is due at ``t0_ns + k`` periods."""
        self.t0_ns = t0_ns

    def next_tick(self, tick: int) -> tuple[int, int]:
        """The next tick's number and time: the tick's own time, or (realtime) the wall clock at its deadline."""
        tick += 1
        due_ns = self.t0_ns + tick * self.period_ns
        if not self.realtime:
            return tick, due_ns
        now_ns = time.monotonic_ns()
        for part, device in self.preparing:  # time to spare: the devices' work, now (each while it lasts)
            if due_ns - now_ns < self.period_ns // 2:
                break
            self.call(part, device.prepare, due_ns + PREPARE_AHEAD_TICKS * self.period_ns)
            now_ns = time.monotonic_ns()
        if now_ns < due_ns:
            self.status.behind_s = 0.0
            time.sleep((due_ns - now_ns) * 1e-9)
            return tick, time.monotonic_ns()
        behind_ns = now_ns - due_ns
        if behind_ns > self.period_ns:  # fell behind: skip the ticks missed, say so
            skipped = behind_ns // self.period_ns
            self._overrun(now_ns, behind_ns, int(skipped))
            tick += int(skipped)
        return tick, now_ns

    def _overrun(self, now_ns: int, behind_ns: int, skipped: int) -> None:
        self.overruns += 1
        self.skipped_since_event += skipped
        self.behind_max_ns = max(self.behind_max_ns, behind_ns)
        self.status.behind_s = behind_ns * 1e-9
        if now_ns >= self.next_overrun_event_ns:
            self.overrun_event(now_ns)

    def overrun_event(self, now_ns: int) -> None:
        """The overruns since the last such event, as one event (how far behind at most, ticks skipped)."""
        if self.skipped_since_event:
            self.on_event(
                Event(
                    now_ns,
                    "overrun",
                    f"loop {self.behind_max_ns * 1e-6:.1f} ms behind its {self.loop_rate_hz:g} Hz rate; "
                    f"{self.skipped_since_event} tick(s) skipped",
                    {"behind_s": self.behind_max_ns * 1e-9, "ticks_skipped": self.skipped_since_event},
                )
            )
            self.next_overrun_event_ns = now_ns + OVERRUN_EVENT_INTERVAL_NS
            self.skipped_since_event, self.behind_max_ns = 0, 0
