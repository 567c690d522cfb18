"""A contact that begins as a pull straight down: a contact, or the tool's weight, which the readings cannot tell.

A session whose tool was identified by the motion alone (no stated mass, ``[haptic] tool_mass``) may have
identified it resting on something: pressed straight up, the support reads as a lighter tool whose centre of
gravity sits towards the point pressed (``stated_weight``). When the support goes, the weight the motion
missed appears as a pull straight down at that point: no twist, a lever the tool's own, and a size that stays
put while the tool moves on; a load hung on the tool reads the same. A lift faster than tissue pushes is a
sudden step (``watch.StepWatch``), held until the motion tells; a slower one (lifted off over 0.1 s) began as
a contact, and 2 N pulled the trainee's hand down to the end of the demo session.

:class:`PullWatch` keeps the residual's mean in the base frame B over the newest ``WINDOW`` samples and judges
its direction when the mean first rises from under ``QUIET_N`` to ``JUDGE_N`` (an onset: the estimators'
contact flags rise later, rls's at its 1 N threshold). Only the session's first onset can be the support
going (it was there since the tool was identified, so nothing before it changed the residual): within
``ONSET_TILT`` of the weight's, that onset is a pull straight down, and the gate holds the force until the
residual is gone (a contact that ended), turns with the world (a contact) or keeps its direction in the world
along the weight (``drift.WEIGHT_TILT``) while the tool turns (the drift watch). Then nothing in the readings
says which it is: the force latches off, and a re-arm, the tool freed, takes the residual as the weight the
motion missed (a contact learned as weight would come back as a push up when it ends: so a person says which).
The price, measured (docs/safety.md): a session's first contact, when it pulls down within ``ONSET_TILT`` of
straight down, is held (latched, if it keeps its direction while the tool turns). With a stated mass the
weight is known and none of this applies (``StatedWeight``).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

WINDOW = 10
"""Samples in the mean (10 ms at 1 kHz): the sensor's noise (0.12 N per axis) averages down to 0.04 N, so the
direction of a 0.3 N mean is known to about 0.15 rad, and a slow lift (20 N/s) is judged 20 ms in."""
JUDGE_N = 0.3
"""An onset is judged when the mean reaches this, N: seven times the mean's noise (no false onsets from it),
and the force rendered before the verdict stays under the 0.5 N of made-up force a fault may put on the hand."""
ONSET_TILT = 0.5
"""The first onset is a pull straight down within this angle of the weight's, rad (29°): its 10 ms mean at
``JUDGE_N`` points within about 8° (1σ, each way across) of the true direction, so a pull straight down falls
outside at 1 in 10,000; ``WEIGHT_TILT`` (14°) would miss one in six. The drift watch's verdict, over half a
second, is then held to ``WEIGHT_TILT``."""
QUIET_N = 0.15
"""...after the mean was under this, N (an onset is judged once, until the residual has gone again)."""
REARM_N, REARM_SHARE = 0.5, 0.2
"""A re-arm after a pull straight down's latch needs the residual within this of the pull that latched, N, or
this share of it: the newest block's mean (one to seven samples of 0.12 N noise an axis) wanders by ~0.2 N,
and a contact since (learned as weight by the re-arm) would be rendered, reversed, when it ends."""
PULL = "pull straight down"
"""The onset the gate holds (the first words of its reason)."""


class PullWatch:
    """Judges the residual's first onset: a pull straight down or not (module docstring). Per sample the work
    is a running sum in Python floats, until the first onset; after it, none."""

    def __init__(self) -> None:
        self.window: deque[list[float]] = deque()
        self.total_B = [0.0, 0.0, 0.0]
        self.armed = False  # the mean was under QUIET_N since the last onset judged
        self.first = True  # no onset judged yet: the next may be the support going

    def add(
        self, contact_force_S: np.ndarray, R_EB: np.ndarray, R_SE: np.ndarray | None, gravity_force_B: list[float]
    ) -> str:
        """One block the primary estimator refined: its contact force (n, 3) N in S, the orientations R_EB
        (n, 3, 3), the sensor's mount R_SE (3, 3; None: S is E) and the identified weight (3,) N in B; what the
        first onset is when it pulls straight down, its size and angle ("" otherwise, or not yet)."""
        if not self.first:
            return ""
        f_E = contact_force_S if R_SE is None else contact_force_S @ R_SE  # (rows: R_ES·f)
        total, window = self.total_B, self.window
        for f in np.matmul(f_E[:, None, :], R_EB)[:, 0, :].tolist():  # rows: R_BE·f, in B
            if not (math.isfinite(f[0]) and math.isfinite(f[1]) and math.isfinite(f[2])):
                continue
            window.append(f)
            total[0], total[1], total[2] = total[0] + f[0], total[1] + f[1], total[2] + f[2]
            if len(window) > WINDOW:
                old = window.popleft()
                total[0], total[1], total[2] = total[0] - old[0], total[1] - old[1], total[2] - old[2]
            if len(window) < WINDOW:
                continue
            size = math.sqrt(total[0] ** 2 + total[1] ** 2 + total[2] ** 2) / WINDOW
            if size < QUIET_N:
                self.armed = True
            elif self.armed and size >= JUDGE_N:
                self.first = False
                angle = off(np.array(total), down_B(gravity_force_B))
                if angle <= ONSET_TILT:
                    return f"{size:.2f} N, {math.degrees(angle):.0f}° off the weight, no stated tool mass"
                return ""
        return ""


def off(u: np.ndarray, v) -> float:
    """The angle between ``u`` and ``v`` (3,), rad (pi when either is zero)."""
    v = np.asarray(v, dtype=float)
    norm = float(np.linalg.norm(u)) * float(np.linalg.norm(v))
    return math.acos(max(-1.0, min(1.0, float(u @ v) / norm))) if norm > 0 else math.pi


def rearm_refusal(latched_B: np.ndarray, residual: tuple, label: str, reidentifies_weight: object) -> str:
    """Why a re-arm of a pull straight down's latch is refused ("" granted): ``latched_B`` (3,) N the pull that
    latched, ``residual`` the newest block's (mean (3,) N in S, R_EB, R_SE); an estimator without
    ``reidentifies_weight`` (None) cannot take it as the weight."""
    if reidentifies_weight is None:
        return f"{label} cannot re-identify the tool's weight: state haptic.tool_mass and start a new session"
    f_S, R_EB, R_SE = residual
    now_B = (R_EB.T if R_SE is None else R_EB.T @ R_SE.T) @ f_S
    miss = float(np.linalg.norm(now_B - latched_B))
    if not miss <= max(REARM_N, REARM_SHARE * float(np.linalg.norm(latched_B))):  # (a NaN refuses too)
        return (
            f"the residual is {miss:.2f} N off the pull that latched (a contact since, or no finite one): free the tool"
        )
    return ""


def down_B(gravity_force_B: list[float]) -> list[float]:
    """Which way is down in B, N (3,): the identified weight, or B's −z when that points up. A support that pushed
    harder than the tool weighs identifies a weight pointing up (a negative mass), and its lift is then a pull
    straight down at 180° from it: B's −z is the way gravity points for an arm mounted upright (mounted
    otherwise, more onsets are held, not fewer)."""
    return list(gravity_force_B) if gravity_force_B[2] < 0 else [0.0, 0.0, -1.0]
