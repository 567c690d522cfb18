"""What the simulated trainee's hand means to do (``sim`` master's ``script``): where it wants the handle, and
which buttons it holds, as a function of time, and of the force it has felt so far.

Each script is a list of moves of the *intent* (a raised cosine from one point to the next in D, m), built
as the session goes: :class:`Palpate` decides where to mark only once it has felt every probe.

* ``press``: down by ``depth``, hold ``hold`` s, back up (the default: a single indentation);
* ``palpate``: presses at ``probes`` points spread over ``span`` along D's x (a hand searching for a stiffer
  inclusion), feels the force of each, goes back to the firmest, presses and holds ``mark_button`` there;
* ``trace``: moves to one end of a line of length ``span`` along D's x, presses down, slides to the other
  end in ``hold`` s while pressed, lifts.
"""

from __future__ import annotations

import math

import numpy as np

SCRIPTS = ("press", "palpate", "trace")
MOVE_S = 0.5
"""How long the hand takes to move across between two presses, s."""
MARK_S = 0.3
"""How long it holds the mark button down at the bottom of the marking press, s."""


class Moves:
    """A timeline of raised-cosine moves of the intent: ``add(duration, to)`` then ``at(t)``."""

    def __init__(self, start_s: float):
        self.end_s = start_s
        self.last = np.zeros(3)
        self.moves: list[tuple[float, float, np.ndarray, np.ndarray]] = []  # (t0, t1, from, to)

    def add(self, duration: float, to) -> tuple[float, float]:
        """Move to ``to`` (m in D) over ``duration`` s after the previous move; its (start, end) s."""
        to = np.asarray(to, dtype=float)
        t0, t1 = self.end_s, self.end_s + duration
        self.moves.append((t0, t1, self.last, to))
        self.end_s, self.last = t1, to
        return t0, t1

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The intent's position (m) and velocity (m/s) at ``t`` s: the last point once the moves are over."""
        for t0, t1, a, b in self.moves:
            if t0 <= t < t1:
                w = math.pi / (t1 - t0)
                s = 0.5 * (1 - math.cos(w * (t - t0)))
                return a + s * (b - a), (0.5 * w * math.sin(w * (t - t0))) * (b - a)
        if self.moves and t < self.moves[0][0]:
            return self.moves[0][2].copy(), np.zeros(3)
        return self.last.copy(), np.zeros(3)


class Press:
    """``press``: down ``depth`` (m), ``hold`` s, up; each way in ``ramp`` s, from ``press_at`` s."""

    def __init__(self, press_at: float, depth: float, ramp: float, hold: float, **_):
        self.press_at, self.depth, self.ramp, self.hold = press_at, depth, ramp, hold

    def intent(self, t: float, force_D: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        s, w = t - self.press_at, math.pi / self.ramp
        if s <= 0 or s >= 2 * self.ramp + self.hold:
            return np.zeros(3), np.zeros(3), 0
        if s < self.ramp:  # going down
            z, vz = -0.5 * self.depth * (1 - math.cos(w * s)), -0.5 * self.depth * w * math.sin(w * s)
        elif s < self.ramp + self.hold:
            z, vz = -self.depth, 0.0
        else:  # coming back up
            u = s - self.ramp - self.hold
            z, vz = -0.5 * self.depth * (1 + math.cos(w * u)), 0.5 * self.depth * w * math.sin(w * u)
        return np.array([0.0, 0.0, z]), np.array([0.0, 0.0, vz]), 0


class Trace:
    """``trace``: to x = −span/2, down ``depth``, slide to +span/2 in ``hold`` s, up."""

    def __init__(self, press_at: float, depth: float, ramp: float, hold: float, span: float, **_):
        half = 0.5 * span
        self.moves = Moves(press_at)
        self.moves.add(MOVE_S, (-half, 0.0, 0.0))
        self.moves.add(ramp, (-half, 0.0, -depth))
        self.moves.add(hold, (half, 0.0, -depth))
        self.moves.add(ramp, (half, 0.0, 0.0))

    def intent(self, t: float, force_D: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        p, v = self.moves.at(t)
        return p, v, 0


class Palpate:
    """``palpate``: ``probes`` presses over ``span`` along x, each held ``hold`` s; the force felt over each
    hold's second half is averaged; then a press at the firmest, with ``mark_button`` held for
    :data:`MARK_S` at its bottom."""

    def __init__(
        self, press_at: float, depth: float, ramp: float, hold: float, span: float, probes: int, mark_button: int
    ):
        self.depth, self.ramp, self.hold, self.mark_button = depth, ramp, hold, mark_button
        self.x = np.linspace(-0.5 * span, 0.5 * span, probes) if probes > 1 else np.zeros(1)
        self.moves = Moves(press_at)
        self.feel_windows: list[tuple[float, float]] = []  # per probe, (start, end) s of what is felt
        for x in self.x:
            self.moves.add(MOVE_S, (x, 0.0, 0.0))
            t0, t1 = self.moves.add(ramp, (x, 0.0, -depth))
            t0, t1 = self.moves.add(hold, (x, 0.0, -depth))
            self.feel_windows.append((t0 + 0.5 * hold, t1))
            self.moves.add(ramp, (x, 0.0, 0.0))
        self.felt = np.zeros(len(self.x))  # N·samples, per probe
        self.count = np.zeros(len(self.x))
        self.mark: tuple[float, float] | None = None  # (start, end) s the button is held

    def intent(self, t: float, force_D: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        for i, (t0, t1) in enumerate(self.feel_windows):
            if t0 <= t < t1:
                self.felt[i] += float(np.linalg.norm(force_D))
                self.count[i] += 1
        if self.mark is None and t >= self.moves.end_s:  # every probe felt: back to the firmest
            best = float(self.x[int(np.argmax(self.felt / np.maximum(self.count, 1)))])
            self.moves.add(MOVE_S, (best, 0.0, 0.0))
            self.moves.add(self.ramp, (best, 0.0, -self.depth))
            t0, t1 = self.moves.add(self.hold, (best, 0.0, -self.depth))
            self.mark = (t1 - MARK_S, t1)
            self.moves.add(self.ramp, (best, 0.0, 0.0))
        p, v = self.moves.at(t)
        pressed = self.mark is not None and self.mark[0] <= t < self.mark[1] and self.mark_button >= 0
        return p, v, (1 << self.mark_button) if pressed else 0


def hand_script(script: str, **options):
    """The script named ``script`` (one of :data:`SCRIPTS`) with the master's options."""
    return {"press": Press, "palpate": Palpate, "trace": Trace}[script](**options)
