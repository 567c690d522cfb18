"""Universal Robots arm geometry: the published DH table, forward and analytic inverse kinematics.

The table ``UR_DH`` is Universal Robots' own "DH Parameters for calculations of
kinematics and dynamics" (universal-robots.com/articles/ur/application-installation/
dh-parameters-for-calculations-of-kinematics-and-dynamics/, last modified 19 Jan 2022;
the CB3 UR3/UR5/UR10 rows as in the CB3 user manual's appendix "Robot DH Parameter",
UR5 series 3). It is a plain constant so other tools (a URDF generator, a
Pinocchio model) build from the very same numbers::

    from hapticlab.plugins.kinematics.ur_arm import UR_DH
    a, d, alpha = UR_DH["ur5e"].a, UR_DH["ur5e"].d, UR_DH["ur5e"].alpha   # (6,) m, m, rad

Convention (classic/distal DH, as UR uses it): link i's transform is
``T_{i-1,i} = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)``, θ_i = q_i (UR has no joint
offsets). Frame 0 is the controller's *Base* frame (the one ``actual_TCP_pose``
is expressed in; ROS's ``base``, which is ``base_link`` turned π about z), frame
6 the tool flange (ROS's ``tool0``; the TCP when the TCP offset is zero). In
hapticlab's names frame 0 is B and frame 6 is E, so ``forward(q)`` gives
``(R_BE, p_BoEo_B)``.

Inverse kinematics is the closed form for this family (three parallel middle
axes, a spherical-free wrist with offsets d4, d5, d6): up to 8 solutions from
the choices shoulder left/right (θ1), wrist up/down (θ5) and elbow up/down
(θ3); ``inverse_nearest`` picks the one closest to a previous configuration and
unwraps each joint by multiples of 2π onto it, so a moving pose gives a
continuous joint path (UR joints turn ±2π).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, overload

import numpy as np

from hapticlab.core.frames import rotvec_from_matrix
from hapticlab.core.host.options import choice

if TYPE_CHECKING:
    import numpy.typing as npt


@dataclass(frozen=True)
class DH:
    """One arm's DH table: six joints, classic convention, SI units.

    Attributes:
        a: (6,) link lengths along x_i, m.
        d: (6,) link offsets along z_{i-1}, m.
        alpha: (6,) link twists about x_i, rad.
    """

    a: np.ndarray
    d: np.ndarray
    alpha: np.ndarray

    if TYPE_CHECKING:  # the dataclass's own __init__ at run time, which takes any sequence of six numbers

        def __init__(self, a: npt.ArrayLike, d: npt.ArrayLike, alpha: npt.ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        for name in ("a", "d", "alpha"):
            value = np.asarray(getattr(self, name), dtype=float)
            value.setflags(write=False)
            object.__setattr__(self, name, value)


_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)

UR_DH: dict[str, DH] = {
    # e-Series (controller 5.x, RTDE at up to 500 Hz)
    "ur3e": DH(
        a=(0.0, -0.24355, -0.2132, 0.0, 0.0, 0.0), d=(0.15185, 0.0, 0.0, 0.13105, 0.08535, 0.0921), alpha=_ALPHA
    ),
    "ur5e": DH(a=(0.0, -0.425, -0.3922, 0.0, 0.0, 0.0), d=(0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996), alpha=_ALPHA),
    "ur10e": DH(
        a=(0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0), d=(0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655), alpha=_ALPHA
    ),
    "ur16e": DH(a=(0.0, -0.4784, -0.36, 0.0, 0.0, 0.0), d=(0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655), alpha=_ALPHA),
    # CB3 (controller 3.x, RTDE at up to 125 Hz)
    "ur3": DH(a=(0.0, -0.24365, -0.21325, 0.0, 0.0, 0.0), d=(0.1519, 0.0, 0.0, 0.11235, 0.08535, 0.0819), alpha=_ALPHA),
    "ur5": DH(a=(0.0, -0.425, -0.39225, 0.0, 0.0, 0.0), d=(0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823), alpha=_ALPHA),
    "ur10": DH(a=(0.0, -0.612, -0.5723, 0.0, 0.0, 0.0), d=(0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922), alpha=_ALPHA),
}
"""Universal Robots' published DH parameters by model name (lower case), frame 0 = Base, frame 6 = flange."""

CB3_MODELS = frozenset({"ur3", "ur5", "ur10"})
"""Models with a CB3 controller (RTDE up to 125 Hz); the others are e-Series (500 Hz)."""

UR5E_FORCE_ACCURACY_N = 4.0
"""The UR5e data sheet's force accuracy of its built-in force/torque sensor (``actual_TCP_force``), N per axis
(its precision: 3.5 N)."""
HOME_Q = np.array([0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
"""A usual start configuration (rad): elbow up, flange pointing down; ``inverse_nearest``'s default reference."""


def _link(dh: DH, i: int, theta: float):
    """DH frame i+1 in frame i for joint angle ``theta`` (rad), in plain floats: (rotation rows, origin)."""
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(dh.alpha[i]), math.sin(dh.alpha[i])
    return ((ct, -st * ca, st * sa), (st, ct * ca, -ct * sa), (0.0, sa, ca)), (dh.a[i] * ct, dh.a[i] * st, dh.d[i])


def link_transform(dh: DH, i: int, theta: float) -> np.ndarray:
    """(4, 4) homogeneous transform of DH frame i+1 in frame i for joint angle ``theta`` (rad)."""
    R, o = _link(dh, i, float(theta))
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, o
    return T


def forward(dh: DH, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flange pose of joint angles ``q`` (6,) rad: ``(R_BE (3, 3), p_BoEo_B (3,) m)`` in the Base frame."""
    R = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    px = py = pz = 0.0
    for i, theta in enumerate(np.asarray(q, dtype=float).tolist()):  # T = T · link_transform(i), in floats
        R_link, (ox, oy, oz) = _link(dh, i, theta)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
        px, py, pz = (
            px + r00 * ox + r01 * oy + r02 * oz,
            py + r10 * ox + r11 * oy + r12 * oz,
            pz + r20 * ox + r21 * oy + r22 * oz,
        )
        R = _mul(R, R_link)
    return np.array(R), np.array([px, py, pz])


@overload
def _wrap(angle: np.ndarray) -> np.ndarray: ...
@overload
def _wrap(angle: float) -> float: ...
def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped into [−π, π)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _mul(A, B):
    """A·B of two 3×3 matrices given as row tuples."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B
    return (
        (a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
        (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
        (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22),
    )


def _mul_t(A, B):
    """Aᵀ·B of two 3×3 matrices given as row tuples."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    return _mul(((a00, a10, a20), (a01, a11, a21), (a02, a12, a22)), B)


def _apply_t(A, v):
    """Aᵀ·v of a 3×3 matrix (row tuples) and a 3-vector."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    x, y, z = v
    return (a00 * x + a10 * y + a20 * z, a01 * x + a11 * y + a21 * z, a02 * x + a12 * y + a22 * z)


def inverse(dh: DH, R_BE: np.ndarray, p_BoEo_B: np.ndarray, q6_singular: float = 0.0) -> np.ndarray:
    """Every joint solution (k, 6) rad, k <= 8, each angle in [−π, π), of a flange pose in the Base frame.

    Derivation (frames as in ``forward``): the wrist point p5 = p − d6·z_E must
    lie at height d4 along z1, which fixes θ1 (two roots); in frame 1 the flange
    orientation is ``Rz(θ2+θ3+θ4) · Ry(−θ5) · Rz(θ6)``, whose last row
    [s5·c6, −s5·s6, c5] gives θ5 (two roots, ±) and θ6; taking links 5 and 6
    off leaves a planar 2R arm (a2, a3) for θ2, θ3 (two roots, elbow up/down)
    and θ4 = θ234 − θ2 − θ3. Poses out of reach
    give no solution (an empty array). At the wrist singularity (sin θ5 = 0)
    only θ2+…+θ4+θ6 is determined; θ6 is then taken as ``q6_singular``.
    """
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R_BE, dtype=float).tolist()
    px, py, pz = np.asarray(p_BoEo_B, dtype=float).tolist()
    a2, a3 = dh.a[1], dh.a[2]
    d4, d6 = dh.d[3], dh.d[5]
    # plain floats throughout: the emulated arm solves this at every RTDE cycle (numpy's per-call cost would
    # dominate: docs/devices.md)
    x5, y5 = px - d6 * r02, py - d6 * r12  # p5 = p − d6·z_E
    r = math.hypot(x5, y5)
    if r < abs(d4) or r == 0.0:
        return np.empty((0, 6))
    phi = math.atan2(y5, x5)
    shoulder = math.asin(min(max(d4 / r, -1.0), 1.0))
    solutions = []
    for theta1 in (phi + shoulder, phi + math.pi - shoulder):
        R01, p01 = _link(dh, 0, theta1)
        R16 = _mul_t(R01, ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22)))  # R_01ᵀ R_BE
        p16 = _apply_t(R01, (px - p01[0], py - p01[1], pz - p01[2]))  # R_01ᵀ (p − p_01)
        # The last row of R_16 is [s5·c6, −s5·s6, c5] (and p_16 z = d4 + d6·c5 by the choice of θ1):
        # atan2 keeps θ5 accurate near sin θ5 = 0, where arccos(c5) would lose half the digits.
        s5_abs = math.hypot(R16[2][0], R16[2][1])
        for sign in (1.0, -1.0):
            theta5 = math.atan2(sign * s5_abs, R16[2][2])
            theta6 = math.atan2(-sign * R16[2][1], sign * R16[2][0]) if s5_abs > 1e-12 else q6_singular
            # T_46 = L4(θ5)·L5(θ6); T_14 = T_16·T_46⁻¹: only its first two rows' x column and origin are needed
            (R4, o4), (R5, o5) = _link(dh, 4, theta5), _link(dh, 5, theta6)
            R46 = _mul(R4, R5)
            p46 = tuple(o4[i] + R4[i][0] * o5[0] + R4[i][1] * o5[1] + R4[i][2] * o5[2] for i in range(3))
            # T_64 = [R_46ᵀ, −R_46ᵀ p_46]; T_14 = [R_16 R_46ᵀ, R_16 (−R_46ᵀ p_46) + p_16]
            q64 = _apply_t(R46, p46)
            (u0, u1, u2), (v0, v1, v2) = R16[0], R16[1]
            theta234 = math.atan2(
                v0 * R46[0][0] + v1 * R46[0][1] + v2 * R46[0][2], u0 * R46[0][0] + u1 * R46[0][1] + u2 * R46[0][2]
            )
            x = p16[0] - (u0 * q64[0] + u1 * q64[1] + u2 * q64[2])  # frame 3's origin in frame 1
            y = p16[1] - (v0 * q64[0] + v1 * q64[1] + v2 * q64[2])
            c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
            if abs(c3) > 1.0 + 1e-12:
                continue
            c3 = min(max(c3, -1.0), 1.0)
            for theta3 in (math.acos(c3), -math.acos(c3)):
                theta2 = math.atan2(y, x) - math.atan2(a3 * math.sin(theta3), a2 + a3 * math.cos(theta3))
                theta4 = theta234 - theta2 - theta3
                solutions.append((theta1, theta2, theta3, theta4, theta5, theta6))
    return _wrap(np.array(solutions, dtype=float).reshape(-1, 6))


def inverse_nearest(
    dh: DH, R_BE: np.ndarray, p_BoEo_B: np.ndarray, q_near: np.ndarray | None = None
) -> np.ndarray | None:
    """The solution (6,) rad closest to ``q_near`` (default ``HOME_Q``), each joint unwrapped by 2π onto it.

    Distance is the largest joint difference (after unwrapping), so the pick is
    the branch a continuously moving arm stays on. None when the pose is out of reach.
    """
    q_near = HOME_Q if q_near is None else np.asarray(q_near, dtype=float)
    candidates = inverse(dh, R_BE, p_BoEo_B, q6_singular=float(_wrap(q_near[5])))
    if len(candidates) == 0:
        return None
    unwrapped = q_near + _wrap(candidates - q_near)
    best = np.argmin(np.abs(unwrapped - q_near).max(axis=1))
    return unwrapped[best]


class URArm:
    """One UR model's kinematics: ``measured_cp`` of joint angles and back.

    Parameters
    ----------
    model : a key of ``UR_DH`` ("ur5e", "ur3e", "ur10e", "ur16e", "ur3", "ur5", "ur10").
    """

    def __init__(self, model: str = "ur5e"):
        choice("model", model, list(UR_DH))
        self.model = model
        self.dh = UR_DH[model]

    @property
    def cb3(self) -> bool:
        """True for a CB3 controller (RTDE at 125 Hz), False for an e-Series (500 Hz)."""
        return self.model in CB3_MODELS

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R_BE, p_BoEo_B)`` of the flange for joint angles ``q`` (6,) rad."""
        return forward(self.dh, q)

    def flange_error(self, q: np.ndarray, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> tuple[float, float]:
        """How far a reported pose is from the flange's at joints ``q`` (6,) rad: (distance m, angle rad)."""
        R_fk, p_fk = self.forward(q)
        return float(np.linalg.norm(p_BoEo_B - p_fk)), float(np.linalg.norm(rotvec_from_matrix(R_fk.T @ R_BE)))

    def inverse(self, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> np.ndarray:
        """Every solution (k <= 8, 6) rad of a flange pose."""
        return inverse(self.dh, R_BE, p_BoEo_B)

    def inverse_nearest(
        self, R_BE: np.ndarray, p_BoEo_B: np.ndarray, q_near: np.ndarray | None = None
    ) -> np.ndarray | None:
        """The solution closest to ``q_near`` (a continuous branch), or None when out of reach."""
        return inverse_nearest(self.dh, R_BE, p_BoEo_B, q_near)
