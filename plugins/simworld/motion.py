"""Motion scripts for the simulated robot: where the flange E is at every time.

A script maps an array of times ``t`` (s) to a :class:`MotionState`: the pose of
the flange E in the robot base B (``R_BE``, ``p_BoEo_B``) and its first and
second time derivatives. The derivatives are **analytic**, not finite
differences. Every script is built from pieces whose derivatives are exact:

* a slerp (geodesic) between two orientations with a quintic time scaling,
  ``R_BE(t) = R_BE_a · Exp(s(t) u)`` with ``u`` the rotation vector from the start
  to the end orientation, expressed in E. Because the axis ``u`` is fixed in E,
  the angular velocity of E in B, expressed in E, is exactly ``ṡ u`` and the
  angular acceleration exactly ``s̈ u``;
* a straight-line move with the same time scaling (velocity ``ṡ Δp``,
  acceleration ``s̈ Δp``);
* a rotation about E's own z axis by an angle ``φ(t)`` (``ω = φ̇ z``, ``ω̇ = φ̈ z``).

The quintic ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵`` has zero first and second derivatives at
both ends, so every script is C2-smooth (continuous angular acceleration and
linear acceleration) including at waypoints and at the end. Scripts are defined
for every t: before 0 they hold the start, after their end they hold the last
pose (random scripts without a waypoint count go on forever).

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

from hapticlab.core.frames import skew, skew_stack
from hapticlab.core.host.options import OptionError, choice, integer, number

__all__ = [
    "HORIZONTAL_R_BE",
    "MOTION_SCRIPTS",
    "NOMINAL_R_BE",
    "AxialRotation",
    "DEFAULT_P_BoEo_B",
    "Hold",
    "MotionScript",
    "MotionState",
    "RandomTour",
    "StaticPoses",
    "make_motion",
    "quintic",
]

MOTION_STREAM = 2
"""SeedSequence spawn key of the motion stream (see ``physics`` for the others)."""

WAYPOINT_BLOCK = 64
"""Random waypoints are drawn this many at a time, each block from its own generator."""

DEFAULT_P_BoEo_B = (0.45, 0.0, 0.35)
"""Default flange position in the base frame, m."""

NOMINAL_R_BE = Rotation.from_rotvec([np.pi, 0.0, 0.0]).as_matrix()
"""Nominal pose, tool pointing down: E's z axis along −z of B (x_E = x_B, y_E = −y_B)."""

HORIZONTAL_R_BE = Rotation.from_rotvec([0.0, np.pi / 2, 0.0]).as_matrix()
"""Tool horizontal: E's z axis along +x of B (x_E = −z_B, y_E = y_B)."""


@dataclass(frozen=True, slots=True)
class MotionState:
    """The flange pose and its derivatives at N times.

    Attributes:
        t: (N,) times, s.
        R_BE: (N, 3, 3) orientation of E in B (``v_B = R_BE @ v_E``).
        p_BoEo_B: (N, 3) position of E's origin from B's origin, in B, m.
        w_BE_E: (N, 3) angular velocity of E relative to B, expressed in E, rad/s.
        alpha_BE_E: (N, 3) angular acceleration of E relative to B, expressed in E, rad/s².
        v_BEo_B: (N, 3) velocity of E's origin in B, expressed in B, m/s.
        a_BEo_B: (N, 3) acceleration of E's origin in B, expressed in B, m/s².
    """

    t: np.ndarray
    R_BE: np.ndarray
    p_BoEo_B: np.ndarray
    w_BE_E: np.ndarray
    alpha_BE_E: np.ndarray
    v_BEo_B: np.ndarray
    a_BEo_B: np.ndarray


def quintic(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Quintic time scaling ``s = 10τ³ − 15τ⁴ + 6τ⁵`` and its derivatives in τ.

    Parameters
    ----------
    tau : (N,) normalised time; clipped to [0, 1].

    Returns
    -------
    s, ds_dtau, d2s_dtau2 : (N,) each. ``s`` runs 0 → 1; both derivatives are
        zero at τ = 0 and τ = 1.
    """
    tau = np.minimum(np.maximum(tau, 0.0), 1.0)  # np.clip, without its per-call overhead
    tau_2 = tau * tau
    rest = 1.0 - tau
    s = tau_2 * tau * (10.0 - 15.0 * tau + 6.0 * tau_2)
    ds = 30.0 * tau_2 * (rest * rest)
    dds = 60.0 * tau * rest * (1.0 - 2.0 * tau)
    return s, ds, dds


def _times(t: float | np.ndarray) -> np.ndarray:
    """Times as a 1-D float array (a scalar becomes one element)."""
    return np.atleast_1d(np.asarray(t, dtype=float)).ravel()


def _rotz(angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations by ``angle`` (rad) about z."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros((len(angle), 3, 3))
    R[:, 0, 0], R[:, 0, 1] = c, -s
    R[:, 1, 0], R[:, 1, 1] = s, c
    R[:, 2, 2] = 1.0
    return R


def _rodrigues(R_a: np.ndarray, R_a_n: np.ndarray, R_a_nn: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) ``R_a Exp(angle · n)`` by Rodrigues' formula, for a unit axis n.

    ``R_a Exp(φ n) = R_a + sin φ · R_a [n]× + (1 − cos φ) · R_a [n]×²``, given
    ``R_a``, ``R_a [n]×`` and ``R_a [n]×²`` (each (3, 3), or (N, 3, 3) per
    sample) and the (N,) angles φ, rad: a sine and a cosine per sample, where
    building a scipy Rotation would cost more than the arithmetic in the live
    loop's reads of a few samples.
    """
    sin_angle = np.sin(angle)[:, None, None]
    versine = (1.0 - np.cos(angle))[:, None, None]
    return R_a + sin_angle * R_a_n + versine * R_a_nn


def _still(t: np.ndarray, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> MotionState:
    """A MotionState holding one pose at every time."""
    n = len(t)
    R_BE_t = np.empty((n, 3, 3))
    R_BE_t[:] = R_BE
    p_BoEo_B_t = np.empty((n, 3))
    p_BoEo_B_t[:] = p_BoEo_B
    zeros = np.zeros((n, 3))
    return MotionState(
        t=t,
        R_BE=R_BE_t,
        p_BoEo_B=p_BoEo_B_t,
        w_BE_E=zeros,
        alpha_BE_E=zeros.copy(),
        v_BEo_B=zeros.copy(),
        a_BEo_B=zeros.copy(),
    )


@dataclass(frozen=True, slots=True)
class _Moves:
    """What a :class:`RandomTour` needs of each move, computed once per move.

    Move k goes from waypoint k (``R_BE_a``, ``p_BoEo_B_a``) to waypoint k + 1.
    With its rotation vector ``u_E = θ n`` (in E; n a unit axis, 0 if θ = 0) and
    ``[n]×`` the cross-product matrix of n, Rodrigues' formula gives the
    orientation at the fraction s of the move as

        R_BE(s) = R_BE_a Exp(s u_E)
                = R_BE_a + sin(sθ) · R_BE_a [n]× + (1 − cos(sθ)) · R_BE_a [n]×²

    (see ``_rodrigues``).

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


class MotionScript:
    """Base of every motion script: ``evaluate(t)`` gives the pose and its derivatives."""

    name: str = ""

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        """The flange pose and its derivatives at times ``t`` (s, scalar or (N,))."""
        raise NotImplementedError

    def pose(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R_BE (N, 3, 3), p_BoEo_B (N, 3))`` at times ``t`` (s)."""
        state = self.evaluate(t)
        return state.R_BE, state.p_BoEo_B


class Hold(MotionScript):
    """A fixed pose: the tool pointing down, optionally tilted and rolled.

    ``R_BE = Rot_B(tilt_axis_B, tilt_deg) · NOMINAL_R_BE · Rot_z(roll_deg)``: the
    roll turns the tool about its own axis, the tilt then leans it about an axis
    given in B. Used for contact experiments (indentation, hanging masses).

    Parameters
    ----------
    tilt_deg : tilt of the tool axis away from straight down, degrees.
    tilt_axis_B : (3,) axis of the tilt in B (normalised here).
    roll_deg : rotation of the tool about its own axis (E's z), degrees.
    p_BoEo_B : (3,) flange position in B, m.
    """

    name = "hold"

    def __init__(
        self,
        tilt_deg: float = 0.0,
        tilt_axis_B: Sequence[float] = (1.0, 0.0, 0.0),
        roll_deg: float = 0.0,
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
    ):
        axis = np.asarray(tilt_axis_B, dtype=float)
        if axis.shape != (3,) or not np.linalg.norm(axis) > 0:
            raise OptionError("tilt_axis_B", f"must be 3 numbers, not all zero (an axis), got {tilt_axis_B!r}")
        tilt = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.deg2rad(tilt_deg))
        roll = Rotation.from_rotvec([0.0, 0.0, np.deg2rad(roll_deg)])
        self.R_BE = tilt.as_matrix() @ NOMINAL_R_BE @ roll.as_matrix()
        self.p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        return _still(_times(t), self.R_BE, self.p_BoEo_B)


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
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
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
        t = _times(t)
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
        R_BE = _rodrigues(
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
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
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


class AxialRotation(MotionScript):
    """The tool held horizontal and turned about its own axis (the paper's 104 g test).

    ``R_BE(t) = HORIZONTAL_R_BE · Rot_z(roll0 + φ(t))``: E's z axis lies along +x
    of B, and E turns about it. The angle φ(t):

    * rest until ``start_s``;
    * ramp up during ``ramp_s``: φ̇ = speed · s(τ) with the quintic s, so the
      angular acceleration rises and falls smoothly (peak 1.875·speed/ramp_s);
    * constant speed;
    * ramp down (mirror of the ramp up), then hold.

    Each ramp turns the tool by speed·ramp_s/2. With ``turns`` the total angle
    is 2π·turns; with ``duration`` (s, from the start of the ramp up to the end
    of the ramp down) the total angle is speed·(duration − ramp_s). Neither
    given: one turn.

    Parameters
    ----------
    speed_deg_s : rotation speed, deg/s (negative turns the other way).
    duration : time from start to stop, ramps included, s.
    turns : number of full turns (alternative to ``duration``).
    ramp_s : duration of each speed ramp, s (> 0).
    start_s : rest before the rotation starts, s.
    roll0_deg : starting roll about the tool axis, degrees.
    p_BoEo_B : (3,) flange position in B, m.
    """

    name = "axial_rotation"

    def __init__(
        self,
        speed_deg_s: float = 30.0,
        duration: float | None = None,
        turns: float | None = None,
        ramp_s: float = 0.2,
        start_s: float = 0.0,
        roll0_deg: float = 0.0,
        p_BoEo_B: Sequence[float] = DEFAULT_P_BoEo_B,
    ):
        if duration is not None and turns is not None:
            raise OptionError("turns", "give either duration or turns, not both")
        if number("speed_deg_s", speed_deg_s, hint=" (deg/s)") == 0:
            raise OptionError("speed_deg_s", "must be a finite number other than 0 (deg/s), got 0")
        number("ramp_s", ramp_s, above=0, hint=" (s)")
        number("start_s", start_s, minimum=0, hint=" (s)")
        self.speed = np.deg2rad(float(speed_deg_s))  # rad/s
        self.ramp_s = float(ramp_s)
        self.start_s = float(start_s)
        self.roll0 = np.deg2rad(float(roll0_deg))
        self.p_BoEo_B = np.asarray(p_BoEo_B, dtype=float)
        if duration is None:
            angle = 2.0 * np.pi * (1.0 if turns is None else float(turns))
            longest_ramp_s = angle / abs(self.speed)
            self.cruise_s = angle / abs(self.speed) - self.ramp_s
        else:
            longest_ramp_s = float(duration) / 2.0
            self.cruise_s = float(duration) - 2.0 * self.ramp_s
        if self.cruise_s < 0:
            raise OptionError(
                "ramp_s",
                f"must be <= {longest_ramp_s:g} s: the rotation is too short for its two speed ramps "
                f"(lower ramp_s or raise duration or turns), got {ramp_s!r}",
            )
        # HORIZONTAL_R_BE [z]× and HORIZONTAL_R_BE [z]×²: Rot_z by Rodrigues' formula (see _rodrigues)
        z_cross = skew(np.array([0.0, 0.0, 1.0]))
        self._R_BE_0_n = HORIZONTAL_R_BE @ z_cross
        self._R_BE_0_nn = self._R_BE_0_n @ z_cross

    @property
    def end_s(self) -> float:
        """Time at which the tool comes to rest again, s."""
        return self.start_s + 2.0 * self.ramp_s + self.cruise_s

    @property
    def total_angle(self) -> float:
        """Signed total rotation about the tool axis, rad."""
        return self.speed * (self.ramp_s + self.cruise_s)

    def angle(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rotation angle φ (rad) and its first two derivatives at times ``t`` (s)."""
        t = _times(t)
        w0, T = self.speed, self.ramp_s
        since_start = t - self.start_s
        # Both ramps at once, (N, 2): time into the ramp up and into the ramp down, in ramps
        u = np.empty((len(t), 2))
        u[:, 0] = since_start / T
        u[:, 1] = (since_start - T - self.cruise_s) / T
        u_clipped = np.minimum(np.maximum(u, 0.0), 1.0)
        # ∫₀^u s(v) dv for the quintic s: 2.5u⁴ − 3u⁵ + u⁶ (equals 1/2 at u = 1).
        s_integral = u_clipped**4 * (2.5 - 3.0 * u_clipped + u_clipped**2)
        s, ds, _ = quintic(u)
        # Speed: w0 · (s_up − s_down); the cruise is the plateau in between.
        phi_dot = w0 * (s[:, 0] - s[:, 1])
        phi_ddot = w0 * (ds[:, 0] - ds[:, 1]) / T
        cruise_time = np.minimum(np.maximum(since_start - T, 0.0), self.cruise_s)
        phi = w0 * (T * s_integral[:, 0] + cruise_time + T * (u_clipped[:, 1] - s_integral[:, 1]))
        return phi, phi_dot, phi_ddot

    def evaluate(self, t: float | np.ndarray) -> MotionState:
        t = _times(t)
        phi, phi_dot, phi_ddot = self.angle(t)
        n = len(t)
        z = np.zeros((n, 3))
        w = z.copy()
        w[:, 2] = phi_dot
        alpha = z.copy()
        alpha[:, 2] = phi_ddot
        return MotionState(
            t=t,
            R_BE=_rodrigues(HORIZONTAL_R_BE, self._R_BE_0_n, self._R_BE_0_nn, self.roll0 + phi),
            p_BoEo_B=np.broadcast_to(self.p_BoEo_B, (n, 3)).copy(),
            w_BE_E=w,
            alpha_BE_E=alpha,
            v_BEo_B=z,
            a_BEo_B=z.copy(),
        )


MOTION_SCRIPTS: dict[str, type[MotionScript]] = {
    "random_tour": RandomTour,
    "static_poses": StaticPoses,
    "axial_rotation": AxialRotation,
    "hold": Hold,
    "indentation": Hold,  # a fixed pose for indentation experiments
}
"""Script names as used in ``[world.motion] script = ...``."""


def make_motion(script: str, **options: object) -> MotionScript:
    """Build a motion script by name (see :data:`MOTION_SCRIPTS`) with its options."""
    return MOTION_SCRIPTS[choice("script", script, tuple(MOTION_SCRIPTS))](**options)
