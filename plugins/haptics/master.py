"""What every haptic master behind a wire shares: its two errors, the force clamp, the link event.

The ``serial`` and ``hid`` plugins raise :class:`MasterOpenError` when a device cannot be opened
and :class:`MasterLostError` when it stops answering (the session then zeroes the force and records
an event); they write only what :func:`clamp_force` lets through, and report changes of their link
counters with :func:`link_event`.
"""

from __future__ import annotations

import math

import numpy as np

from hapticlab.core.errors import UserError
from hapticlab.core.types import Event

ZERO3_F32 = np.zeros(3, np.float32)
CLAMP_MARGIN = 1.0 - 1e-6  # float32 rounding of a force scaled to the limit stays below the limit


class MasterOpenError(UserError, ConnectionError):
    """The master could not be opened or did not answer the handshake; the message names the port and why."""


class MasterLostError(ConnectionError):
    """The master stopped answering, went away, or sent bad replies beyond the limit; the message says which.

    ``cause`` is one of ``"gone"`` (the port failed: unplugged), ``"restarted"``
    (the device forgot the handshake), ``"silent"`` (no reply), ``"errors"``
    (bad replies in a row, a device fault) or ``"lost"`` (still lost, not retried).
    """

    def __init__(self, message: str, cause: str = "silent"):
        super().__init__(message)
        self.cause = cause


def clamp_force(force_D: np.ndarray, max_force: float) -> np.ndarray:
    """(3,) float32 force for the wire: finite, with a norm at most ``max_force`` N, direction kept.

    A force with any non-finite component is zero (nothing but zero can be
    trusted of it); a finite one of any size, up to 1.8e308 N, is scaled down
    along its direction without overflowing (``math.hypot`` scales as it goes).
    Plain floats, not numpy: this runs once a tick on three numbers.
    """
    try:
        x, y, z = (float(v) for v in force_D)
    except (TypeError, ValueError):
        return ZERO3_F32.copy()
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return ZERO3_F32.copy()
    norm = math.hypot(x, y, z)
    if norm > max_force:
        k = max_force * CLAMP_MARGIN / norm
        x, y, z = x * k, y * k, z * k
    return np.array((x, y, z), dtype=np.float32)


def link_event(t_ns: int, counters: dict[str, int], reported: dict[str, int]) -> Event | None:
    """A ``haptic_link`` event naming the link counters that changed since ``reported`` (None if none did)."""
    changed = {k: v for k, v in counters.items() if reported.get(k, 0) != v}
    if not changed:
        return None
    return Event(t_ns, "haptic_link", "haptic link: " + ", ".join(f"{k} {v}" for k, v in changed.items()), changed)
