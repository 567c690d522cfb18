"""The ``random_tour`` and ``static_poses`` motion scripts: smooth moves through random orientations.

Random scripts are deterministic from ``seed``: waypoints are drawn in blocks of
:data:`WAYPOINT_BLOCK`, block ``b`` from ``numpy.random.default_rng(
SeedSequence(seed, spawn_key=(MOTION_STREAM, b)))``, so the pose at a time never
depends on which times were asked for before.

Frames: B robot base, E flange. ``R_BE`` maps vectors from E into B.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.frames import skew_stack
from hapticlab.core.host.options import integer, number
from hapticlab.plugins.simworld.motion.script import (
    NOMINAL_R_BE,
    DEFAULT_P_BoEo_B,
    MotionScript,
    MotionState,
    as_times,
    quintic,
    rodrigues,
)

__all__ = ["MOTION_STREAM", "WAYPOINT_BLOCK", "RandomTour", "StaticPoses"]

MOTION_STREAM = 2
"""SeedSequence spawn key of the motion stream (``simworld/randomness.py`` has the others)."""

WAYPOINT_BLOCK = 64
"""Random waypoints are drawn this many at a time, each block from its own generator."""


def _rotz(angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations by ``angle`` (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((len(angle), 3, 3))
    R[:, 0, 0], R[:, 0, 1] = c, -s
    R[:, 1, 0], R[:, 1, 1] = s, c
    R[:, 2, 2] = 1.0
    return R


@dataclass(frozen=True, slots=True)
class _Moves:
    """What a :class:`RandomTour` needs of each move, computed once per move.

    Move k goes from waypoint k (``R_BE_a``, ``p_BoEo_B_a``) to waypoint k + 1.
    With its rotation vector ``u_E = θ n`` (in E; n a unit axis, 0 if θ = 0) and
    ``[n]×`` the cross-product matrix of n, Rodrigues' formula gives the
    orientation at the fraction s of the move as

        R_BE(s) = R_BE_a Exp(s u_E)
                = R_BE_a + sin(sθ) · R_BE_a [n]× + (1 − cos(sθ)) · R_BE_a [n]×²

    (see ``rodrigues``).

    Attributes:
        u_E: (m, 3) rotation vector of each move, in E, rad.
        angle: (m,) its angle θ = |u_E|, rad.
        R_BE_a: (m, 3, 3) orientation at the start of each move.
        R_BE_a_n: (m, 3, 3) ``R_BE_a [n]×``.
        R_BE_a_nn: (m, 3, 3) ``R_BE_a [n]×²``.
        p_BoEo_B_a: (m, 3) flange position at the start of each move, in B, m.
        step_B: (m, 3) flange displacement over each move, in B, m.
    """

    u_E: np.ndarray
    angle: np.ndarray
    R_BE_a: np.ndarray
    R_BE_a_n: np.ndarray
    R_BE_a_nn: np.ndarray
    p_BoEo_B_a: np.ndarray
    step_B: np.ndarray

    @classmethod
    def between(cls, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> _Moves:
        """The m moves between m + 1 consecutive waypoints: ``R_BE`` (m+1, 3, 3), ``p_BoEo_B`` (m+1, 3) m."""
        R_a, R_b = R_BE[:-1], R_BE[1:]
        R_ab = np.transpose(R_a, (0, 2, 1)) @ R_b  # R_EaEb: end orientation seen from the start
        u_E = Rotation.from_matrix(R_ab).as_rotvec()
        angle = np.linalg.norm(u_E, axis=1)
        axis_E = np.divide(u_E, angle[:, None], out=np.zeros_like(u_E), where=angle[:, None] > 0)
        n_cross = skew_stack(axis_E)
        R_a_n = R_a @ n_cross
        return cls(
            u_E=u_E,
            angle=angle,
            R_BE_a=R_a.copy(),
            R_BE_a_n=R_a_n,
            R_BE_a_nn=R_a_n @ n_cross,
            p_BoEo_B_a=p_BoEo_B[:-1].copy(),
            step_B=p_BoEo_B[1:] - p_BoEo_B[:-1],
        )

    def __len__(self) -> int:
        return len(self.angle)

    def extended(self, more: _Moves) -> _Moves:
        """These moves followed by ``more``."""
        return _Moves(
            *(np.concatenate([getattr(self, field.name), getattr(more, field.name)]) for field in fields(self))
        )


class RandomTour(MotionScript):
    """Smooth moves through random orientations (the paper's identification motion).

    Waypoint 0 is the nominal pose (tool pointing down). Each further waypoint
    tilts the tool axis away from straight down by an angle whose cosine is
    uniform in [cos(max_tilt), 1] (uniform over the spherical cap), towards a
    uniformly random horizontal direction, and rolls the tool about its own axis
    by a uniform angle in ±max_roll_deg. With ``max_translation`` > 0 the flange
    also moves to a random offset within ±max_translation (m, per axis of B).

    Time line: move from waypoint k to k+1 during ``segment_s`` (slerp with
    quintic time scaling, so the robot starts and stops at rest), then hold for
    ``dwell_s``; repeat. With ``waypoints`` set, the tour ends at that waypoint
    and holds it; otherwise it goes on forever.

    Parameters
    ----------
    seed : seed of the waypoints.
    max_tilt_deg : largest tilt of the tool axis from straight down, degrees.
    max_roll_deg : largest roll about the tool axis, degrees (either sign).
    segment_s : duration of one move, s.
    dwell_s : hold at each waypoint after arriving, s.
    max_translation : largest flange offset per axis from ``p_BoEo_B``, m.
    waypoints : number of random waypoints (None: endless).
    p_BoEo_B : (3,) flange position at the nominal pose, in B, m.
    """

    name = "random_tour"

    def __init__(
        self,
        seed: int = 1,
        max_tilt_deg: float = 75.0,
        max_roll_deg: float = 90.0,
        segment_s: float = 1.5,
        dwell_s: float = 0.0,
        max_translation: float = 0.0,
        waypoints: int | None = None,
        p_BoEo_B: Sequence[float] | np.ndarray = DEFAULT_P_BoEo_B,
    ):
        number("segment_s", segment_s, above=0, hint=" (s)")
        number("dwell_s", dwell_s, minimum=0, hint=" (s)")
        if waypoints is not None:
            integer("waypoints", waypoints, minimum=1)
        number("max_tilt_deg", max_tilt_deg, minimum=0, maximum=180, hint=" (degrees)")
        self.seed = int(seed)
        self.max_tilt_deg = float(max_tilt_deg)
        self.max_roll_deg = float(max_roll_deg)
        self.segment_s = float(segment_s)
        self.dwell_s = float(dwell_s)
        self.max_translation = float(max_translation)
        self.waypoints = waypoints
        self.p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)
        # Waypoint cache, extended block by block: orientations, flange offsets,
        # and what the evaluation needs of each move (replaced whole, never edited,
        # so a reader without the lock always sees a consistent table).
        self._R_BE = NOMINAL_R_BE[None].copy()
        self._offset_B = np.zeros((1, 3))
        self._moves = _Moves.between(self._R_BE, self.p_BoEo_B + self._offset_B)
        self._lock = threading.Lock()

    @property
    def period_s(self) -> float:
        """Time from leaving one waypoint to leaving the next, s."""
        return self.segment_s + self.dwell_s

    def hold_midpoints(self, count: int) -> np.ndarray:
        """(count,) times in the middle of the holds at waypoints 1..count, s."""
        k = np.arange(count)
        return k * self.period_s + self.segment_s + 0.5 * self.dwell_s

    def _draw_block(self, block: int) -> tuple[np.ndarray, np.ndarray]:
        """Random waypoints 1 + block·WAYPOINT_BLOCK onwards: (R_BE (n,3,3), offset_B (n,3))."""
        rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(MOTION_STREAM, block)))
        n = WAYPOINT_BLOCK
        heading = rng.uniform(0.0, 2.0 * np.pi, n)
        cos_tilt = rng.uniform(np.cos(np.deg2rad(self.max_tilt_deg)), 1.0, n)
        roll = rng.uniform(-1.0, 1.0, n) * np.deg2rad(self.max_roll_deg)
        offset_B = rng.uniform(-1.0, 1.0, (n, 3)) * self.max_translation
        tilt_axis_B = np.stack([np.cos(heading), np.sin(heading), np.zeros(n)], axis=1)
        tilt = Rotation.from_rotvec(tilt_axis_B * np.arccos(cos_tilt)[:, None])
        R_BE = tilt.as_matrix() @ NOMINAL_R_BE @ _rotz(roll)
        return R_BE, offset_B

    def _ensure(self, count: int) -> None:
        """Make sure waypoints 0..count-1 (and the moves between them) are cached."""
        if len(self._moves) >= count - 1:  # the usual case; no lock needed: the tables only grow
            return
        with self._lock:
            while len(self._R_BE) < count:
                block = (len(self._R_BE) - 1) // WAYPOINT_BLOCK
                R_new, offset_new = self._draw_block(block)
                self._R_BE = np.concatenate([self._R_BE, R_new])
                self._offset_B = np.concatenate([self._offset_B, offset_new])
            first = len(self._moves)  # waypoint at the start of the first missing move
            if first < len(self._R_BE) - 1:
                more = _Moves.between(self._R_BE[first:], self.p_BoEo_B + self._offset_B[first:])
                self._moves = self._moves.extended(more)

    def waypoint_poses(self, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The first ``count`` waypoints: ``(R_BE (count, 3, 3), p_BoEo_B (count, 3))``."""
        self._ensure(count)
        return self._R_BE[:count].copy(), self.p_BoEo_B + self._offset_B[:count]

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        t = as_times(t)
        t_clamped = np.maximum(t, 0.0)
        k = np.floor(t_clamped / self.period_s).astype(np.int64)  # index of the move under way
        local = t_clamped - k * self.period_s  # time since leaving waypoint k, s
        if self.waypoints is not None:
            done = k >= self.waypoints
            k = np.where(done, self.waypoints - 1, k)
            local = np.where(done, self.period_s, local)
        self._ensure(int(k.max(initial=0)) + 2)
        moves = self._moves

        s, ds, dds = quintic(local / self.segment_s)
        s_dot = ds / self.segment_s
        s_ddot = dds / self.segment_s**2

        # R_BE_a Exp(s u_E) (see _Moves); x.take(k, axis=0) is x[k] without the cost of fancy indexing
        R_BE = rodrigues(
            moves.R_BE_a.take(k, axis=0),
            moves.R_BE_a_n.take(k, axis=0),
            moves.R_BE_a_nn.take(k, axis=0),
            s * moves.angle[k],
        )
        u_E = moves.u_E.take(k, axis=0)
        step_B = moves.step_B.take(k, axis=0)
        return MotionState(
            t=t,
            R_BE=R_BE,
            p_BoEo_B=moves.p_BoEo_B_a.take(k, axis=0) + s[:, None] * step_B,
            w_BE_E=s_dot[:, None] * u_E,
            alpha_BE_E=s_ddot[:, None] * u_E,
            v_BEo_B=s_dot[:, None] * step_B,
            a_BEo_B=s_ddot[:, None] * step_B,
        )


class StaticPoses(RandomTour):
    """Random poses held still, with smooth moves in between (the paper's 150 random poses).

    The same waypoints as :class:`RandomTour` with ``segment_s = move_s`` and
    ``dwell_s = hold_s``. ``hold_midpoints(n)`` gives the times in the middle of
    the first n holds (where a static measurement would be taken).

    Parameters
    ----------
    seed, max_tilt_deg, max_roll_deg, max_translation, p_BoEo_B : as RandomTour.
    hold_s : time held still at each pose, s.
    move_s : duration of each move, s.
    poses : number of random poses (None: endless).
    """

    name = "static_poses"

    def __init__(
        self,
        seed: int = 1,
        max_tilt_deg: float = 75.0,
        max_roll_deg: float = 90.0,
        hold_s: float = 1.0,
        move_s: float = 2.0,
        max_translation: float = 0.0,
        poses: int | None = None,
        p_BoEo_B: Sequence[float] | np.ndarray = DEFAULT_P_BoEo_B,
    ):
        super().__init__(
            seed=seed,
            max_tilt_deg=max_tilt_deg,
            max_roll_deg=max_roll_deg,
            segment_s=move_s,
            dwell_s=hold_s,
            max_translation=max_translation,
            waypoints=poses,
            p_BoEo_B=p_BoEo_B,
        )
