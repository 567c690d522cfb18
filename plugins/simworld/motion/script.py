"""What every motion script is: the :class:`MotionScript` interface, the :class:`MotionState` it gives, and
the pieces with exact derivatives the scripts are built of (the quintic time scaling, Rodrigues' formula).

Frames: B robot base, E flange. ``R_BE`` maps vectors from E into B.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "HORIZONTAL_R_BE",
    "NOMINAL_R_BE",
    "DEFAULT_P_BoEo_B",
    "MotionScript",
    "MotionState",
    "as_times",
    "quintic",
    "rodrigues",
    "still",
]

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


def as_times(t: float | np.ndarray) -> np.ndarray:
    """Times as a 1-D float array (a scalar becomes one element)."""
    return np.atleast_1d(np.asarray(t, dtype=float)).ravel()


def rodrigues(R_a: np.ndarray, R_a_n: np.ndarray, R_a_nn: np.ndarray, angle: np.ndarray) -> np.ndarray:
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


def still(t: np.ndarray, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> MotionState:
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
