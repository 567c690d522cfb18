"""A step in the residual the motion has yet to explain: the force held until it tells what the step was.

A sudden step (``watch.StepWatch``: faster than soft tissue pushes) or a session's first residual pulling
straight down (``pull.PullWatch``) opens a :class:`Doubt`, and the gate holds the force while one is open.
It closes when the drift watch gives a verdict the gate acts on (a contact, a weight step, a bias step; a
pull's latches), when the robot's own wrench confirms a contact, or when the estimator has seen free motion
for ``DOUBT_FREE_NS``.
"""

from __future__ import annotations

from hapticlab.sessions.live.drift import MIN_OFFSET_N

DOUBT_FREE_NS = 100_000_000
"""A doubt is over once the estimator has seen free motion this long (0.1 s): the step went away."""
SUDDEN = "sudden step"
"""The kind of doubt a step faster than any contact opens (the other: ``pull.PULL``)."""


class Doubt:
    """The step in hand (falsy when there is none)."""

    def __init__(self) -> None:
        self.what = ""  # the step, as its event says it ("" none)
        self.kind = SUDDEN
        self.from_contact = False  # the estimator saw a contact when it began: only its end or the sensor tells
        self.free_since_ns: int | None = None  # the estimator has seen free motion since (None: a contact now)

    def __bool__(self) -> bool:
        return bool(self.what)

    def __str__(self) -> str:
        return f"the {self.kind} ({self.what})"

    def open(self, what: str, kind: str, contact_now: bool) -> None:
        """A step ``what`` of ``kind``: a step within a doubt keeps where (and how) the first one began (a pull
        straight down is the contact's own onset, not a step within one)."""
        if not self.what:
            self.from_contact, self.kind = contact_now and kind == SUDDEN, kind
        self.what, self.free_since_ns = what, None

    def close(self) -> None:
        self.what = ""

    def watch_free(self, contact_now: bool, offset_S: list[float], t_ns: int) -> None:
        """The estimator's newest contact flag and 20 ms mean of its residual (3,) N in S (one sample's noise
        alone passes ``MIN_OFFSET_N``), at ``t_ns``: free motion this long closes the doubt."""
        f = offset_S
        if contact_now or f[0] * f[0] + f[1] * f[1] + f[2] * f[2] >= MIN_OFFSET_N**2:
            self.free_since_ns = None
        elif self.free_since_ns is None:
            self.free_since_ns = t_ns
        elif t_ns - self.free_since_ns >= DOUBT_FREE_NS:
            self.what = ""

    def reason(self) -> str:
        """The reason the force is held while the doubt is open."""
        kind = "sudden force step" if self.kind == SUDDEN else self.kind
        return f"{kind} ({self.what}): held until the motion tells a contact from the sensor"
