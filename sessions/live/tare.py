"""The sensor's zero, moved only when someone asks: a tare, judged and recorded.

Users of UR's and ATI's own software complain most about silent zeroing ("auto-bias at program start"):
a zero taken while the tool touched something, or with the tool's weight in it, makes a force out of
nothing. hapticlab never zeroes by itself. A tare is asked for by the Python API
(:meth:`~.loop.LiveLoop.tare`), the ``t`` key of ``hapticlab run`` or the device's ``haptic.tare_button``,
and judged over the ``WINDOW_NS`` that follows (hold the tool still and free for 0.1 s; nothing is
kept between tares, so a session that never asks pays nothing):

* **refused** (the event ``tare_refused``, naming why) while the haptic force is held for any reason (a
  fault, a latched stop, the tool not yet identified: until it is, no reading tells a contact from the
  tool's weight), while the estimator cannot re-identify its bias, while the tool moved in the last
  window (turned over ``STILL_TURN_RAD`` or moved over ``STILL_MOVE_M``), and while it touches something
  (the estimator's contact flag, or a mean residual over ``TOUCH_N``, in that window);
* **granted** (the event ``sensor_tared``, with the values removed): the mean reading of that window
  becomes the zero, subtracted from every following reading in S before the gate and the estimators
  see it (the recording keeps the sensor's own readings: nothing recorded is lost); the estimator
  re-identifies its bias, the force held until it has (the gate's bias-step path, ``hold_cause`` "tare").
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from hapticlab.core.types import AlignedSamples, Estimates, Event

if TYPE_CHECKING:
    from hapticlab.sessions.live.gate import HapticGate

WINDOW_NS = 100_000_000
"""The readings a tare averages, and the time the tool must have been still and free: 0.1 s."""
MIN_SAMPLES = 5
"""Fewest usable readings in the window for a tare (fewer: the sensor's data is not there to zero)."""
STILL_TURN_RAD = math.radians(0.25)
"""The most the tool may turn within the window and still count as still, rad (0.25°: a pose's jitter)."""
STILL_MOVE_M = 0.5e-3
"""The most the tool may move within the window and still count as still, m (0.5 mm)."""
TOUCH_N = 0.2
"""The window's mean residual force above which the tool is taken to touch something, N (a touch the
estimator's contact flag is blind to, removed by the zero, would come back as a pull once released)."""


@dataclasses.dataclass(frozen=True)
class _Seen:
    """One estimated block, as a request is judged by it."""

    t_ns: int  # its newest sample's time, ns
    R_EB: np.ndarray  # (3, 3) its newest orientation
    p_BoEo_B: np.ndarray | None  # (3,) its newest position, m (None: the kinematics gives none)
    wrench_sum: np.ndarray  # (6,) the sum of its readings (zeroed), N and N·m
    n: int  # its samples
    contact: bool  # the estimator flagged a contact in it
    residual_sum: np.ndarray  # (3,) the sum of its residual (contact) forces in S, N


class Tare:
    """The zero asked for, and what a request is judged by.

    Attributes:
        requests: tare requests not yet honoured, by source (``"api"``, ``"key t"``, ``"button 2"``).
        zero: (6,) the reading subtracted from every reading, force N then torque N·m, in S (0 until a tare).
        collecting: a window is being gathered for the requests taken (the loop feeds :meth:`watch` then).
    """

    def __init__(self) -> None:
        self.requests: deque[str] = deque()
        self.zero = np.zeros(6)
        self.active = False  # (a zero set: every block is shifted by it)
        self.collecting = False
        self._since_ns = 0  # (when the window began)
        self._sources: list[str] = []  # (the requests it answers)
        self._seen: deque[_Seen] = deque()

    def apply(self, block: AlignedSamples) -> AlignedSamples:
        """``block`` less the zero (the same block while no tare has been granted)."""
        if not self.active:
            return block
        return dataclasses.replace(
            block, force_S=block.force_S - self.zero[:3], torque_S=block.torque_S - self.zero[3:]
        )

    def watch(self, block: AlignedSamples, est: Estimates) -> None:
        """The estimated (usable, zeroed) ``block`` and its estimates, while a window is open (kept ``WINDOW_NS``)."""
        p = None if block.p_BoEo_B is None else block.p_BoEo_B[-1]
        wrench = np.concatenate((block.force_S.sum(axis=0), block.torque_S.sum(axis=0)))
        residual = est.contact_force_S.sum(axis=0)
        t_ns = int(block.t_ns[-1])
        self._seen.append(_Seen(t_ns, block.R_EB[-1], p, wrench, len(block), bool(est.contact.any()), residual))
        while self._seen[0].t_ns < t_ns - WINDOW_NS:
            self._seen.popleft()

    def honour(self, now_ns: int, gate: HapticGate) -> list[Event]:
        """At each tick with requests or a window open: the requests taken into a window (refused at once while
        the ``gate`` holds the force), judged once it is full. The verdict is one event for the requests it
        answers (``sensor_tared`` with ``removed_S`` and ``zero_S``, (6,) N and N·m in S, or ``tare_refused``);
        a granted tare holds the force until the estimator has re-identified its bias."""
        if not self.collecting:
            taken = []
            while self.requests:  # (popleft: a request another thread appends meanwhile is kept for the next)
                taken.append(self.requests.popleft())
            self._sources = list(dict.fromkeys(taken))  # (each source once)
            self.collecting, self._since_ns = True, now_ns
            self._seen.clear()
        held = gate.reason(now_ns)
        if not held and now_ns - self._since_ns < WINDOW_NS:
            return []  # (the window still filling)
        self.collecting = False
        source = ", ".join(self._sources)
        why = self.refusal(now_ns, held, gate.reidentifies is not None, gate.label)
        if why:
            return [Event(now_ns, "tare_refused", f"tare by {source} refused: {why}", {"source": source})]
        removed, zero = self.take()
        f, t = removed[:3], removed[3:]
        message = f"sensor tared by {source}: ({f[0]:.3f}, {f[1]:.3f}, {f[2]:.3f}) N and "
        message += f"({t[0]:.4f}, {t[1]:.4f}, {t[2]:.4f}) N·m removed from every following reading; "
        message += f"{gate.label} re-identifies its bias, the force held until it has"
        gate.tared()
        return [
            Event(
                now_ns,
                "sensor_tared",
                message,
                {"source": source, "removed_S": removed.tolist(), "zero_S": zero.tolist()},
            )
        ]

    def own(self, params: dict[str, list[float]]) -> dict[str, list[float]]:
        """``params`` in the sensor's own readings (:func:`own_zero`; the same dict while no tare was granted)."""
        return own_zero(params, self.zero) if self.active else params

    def unanswered(self, end_ns: int) -> list[Event]:
        """At the session's end: the requests still waiting (or in a window) refused, each answered."""
        sources = [*self._sources] if self.collecting else []
        while self.requests:
            sources.append(self.requests.popleft())
        self.collecting = False
        if not sources:
            return []
        source = ", ".join(dict.fromkeys(sources))
        return [Event(end_ns, "tare_refused", f"tare by {source} refused: the session ended", {"source": source})]

    def refusal(self, now_ns: int, held: str, reidentifies: bool, label: str) -> str:
        """Why a tare at ``now_ns`` must be refused ("" when it may be granted); ``held``: the gate's reason."""
        if held:
            return f"the force is held ({held}): a zero taken now could take in a fault or a contact"
        if not reidentifies:
            return f"{label} cannot re-identify its bias after a tare"
        seen = [s for s in self._seen if s.t_ns >= now_ns - WINDOW_NS]
        span = f"the last {WINDOW_NS * 1e-9:g} s"
        if sum(s.n for s in seen) < MIN_SAMPLES or seen[-1].t_ns - seen[0].t_ns < WINDOW_NS // 2:
            return f"too few readings in {span} to judge the tool still and free"
        first = seen[0]
        turned = max(_angle(first.R_EB, s.R_EB) for s in seen)
        moved = max(_distance(first.p_BoEo_B, s.p_BoEo_B) for s in seen)
        if turned > STILL_TURN_RAD or moved > STILL_MOVE_M:
            return f"the tool is moving (turned {math.degrees(turned):.2f}°, moved {moved * 1e3:.2f} mm in {span})"
        touch = float(np.linalg.norm(np.sum([s.residual_sum for s in seen], axis=0))) / sum(s.n for s in seen)
        if any(s.contact for s in seen) or touch > TOUCH_N:
            return f"the tool is in contact (a mean residual of {touch:.2f} N over {span})"
        return ""

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """Take the window's mean reading as the new zero: (removed, zero), each (6,) N and N·m in S (``removed``
        the change of the zero, what leaves every following reading)."""
        removed = np.sum([s.wrench_sum for s in self._seen], axis=0) / sum(s.n for s in self._seen)
        self.zero = self.zero + removed
        self.active = True
        self._seen.clear()  # (what follows is read against the new zero)
        return removed, self.zero.copy()


def own_zero(params: dict[str, list[float]], zero: np.ndarray) -> dict[str, list[float]]:
    """``params`` identified against a tared zero, turned to the sensor's own readings: the biases plus the zero
    ((6,) N, N·m; the weight and centre of gravity do not move: ``f − bias_force_S`` is the same either way)."""
    own = dict(params)
    for key, part in (("bias_force_S", zero[:3]), ("bias_torque_S", zero[3:])):
        if key in own:
            own[key] = (np.asarray(own[key], dtype=float) + part).tolist()
    return own


def _distance(p_a: np.ndarray | None, p_b: np.ndarray | None) -> float:
    """The distance between two positions, m (0 where the kinematics gives none)."""
    return 0.0 if p_a is None or p_b is None else float(np.linalg.norm(p_b - p_a))


def _angle(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The angle between two orientations, rad."""
    c = (float(np.trace(R_a.T @ R_b)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))
