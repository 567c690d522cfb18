"""Soft tissue the tool can press into: a contact force that depends on where the tool is.

The other contacts (``contacts.Indentation``, ``contacts.HangingMass``) are forces
scheduled in time. In a teleoperated session the trainee decides where the
tool goes, so the tissue's reaction must follow from the tool's position:
:class:`Tissue` is a Kelvin–Voigt half-space. With ``n`` its outward unit
normal (from the tissue into free space), ``q`` a point of its undeformed
surface, the contact point ``x`` (the tool tip) and its velocity ``ẋ``, all in
the robot base B::

    depth d = (q − x) · n                        (> 0: the tip is in the tissue)
    f_B     = max(0, k·d − c·(ẋ · n)) · n        while d > 0, else 0

k the stiffness (N/m), c the damping (N·s/m). The force only pushes (tissue
never pulls the tool in), and it is zero at the surface, so the force
starts continuously as the tip touches. Soft tissues under a 5 mm probe are
of the order 100–1000 N/m (liver ~ 200–500 N/m); the default 300 N/m gives
3 N at 1 cm depth.

An **inclusion** (a stiffer nodule under the surface, what palpation looks for: ``sessions/tasks``) is a
vertical cylinder of radius ``inclusion_radius`` about ``inclusion_B`` where the stiffness is
``inclusion_stiffness``: a tip pressed within it meets the nodule (breast and prostate nodules are several
times stiffer than the tissue around them, Krouskop et al. 1998).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hapticlab.core.host.options import OptionError, check, check_fields, number, vector


@dataclass(frozen=True, slots=True)
class Tissue:
    """A soft-tissue half-space in B that pushes back on the tool tip pressed into it.

    Attributes:
        surface_B: (3,) a point of the undeformed surface, in B, m.
        normal_B: (3,) outward normal of the surface (normalised here), in B.
        stiffness: k, the push per metre of depth, N/m (> 0).
        damping: c, the push per m/s the tip moves into the tissue, N·s/m (>= 0).
        point_S: (3,) the point of the tool that touches, in S, m; None: the tool tip.
        inclusion_B: (3,) the inclusion's centre, in B, m; None: no inclusion.
        inclusion_radius: its radius across the normal, m.
        inclusion_stiffness: the stiffness a tip pressed within it meets, N/m.
    """

    surface_B: np.ndarray = (0.45, 0.0, 0.0)  # type: ignore[assignment]  # an array after __post_init__
    normal_B: np.ndarray = (0.0, 0.0, 1.0)  # type: ignore[assignment]  # an array after __post_init__
    stiffness: float = 300.0
    damping: float = 2.0
    point_S: np.ndarray | None = None
    inclusion_B: np.ndarray | None = None
    inclusion_radius: float = 0.006
    inclusion_stiffness: float = 12000.0

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "surface_B": vector,
                "normal_B": vector,
                "stiffness": check(number, above=0, hint=" (N/m)"),
                "damping": check(number, minimum=0, hint=" (N·s/m)"),
                "inclusion_radius": check(number, above=0, maximum=1, hint=" (m)"),
                "inclusion_stiffness": check(number, above=0, hint=" (N/m)"),
            },
        )
        norm = float(np.linalg.norm(self.normal_B))
        if norm == 0:
            raise OptionError(
                "normal_B", f"must be 3 numbers, not all zero (a direction), got {self.normal_B.tolist()!r}"
            )
        object.__setattr__(self, "normal_B", self.normal_B / norm)
        if self.point_S is not None:
            object.__setattr__(self, "point_S", vector("point_S", self.point_S))
        if self.inclusion_B is not None:
            object.__setattr__(self, "inclusion_B", vector("inclusion_B", self.inclusion_B))

    def depth(self, x_B: np.ndarray) -> np.ndarray:
        """(N,) how deep the points ``x_B`` (N, 3) m are in the tissue, m (negative: above it)."""
        return (self.surface_B - x_B) @ self.normal_B

    def force_B_at(self, x_B: np.ndarray, v_B: np.ndarray) -> np.ndarray:
        """(N, 3) force of the tissue on the tool, in B, N, for the touching point at ``x_B`` (N, 3) m
        moving at ``v_B`` (N, 3) m/s."""
        depth = self.depth(x_B)
        stiffness: float | np.ndarray = self.stiffness
        if self.inclusion_B is not None:
            across = x_B - self.inclusion_B
            across = across - np.outer(across @ self.normal_B, self.normal_B)
            inside = np.linalg.norm(across, axis=1) < self.inclusion_radius
            stiffness = np.where(inside, self.inclusion_stiffness, self.stiffness)
        push = stiffness * depth - self.damping * (v_B @ self.normal_B)
        magnitude = np.where(depth > 0, np.maximum(push, 0.0), 0.0)
        return magnitude[:, None] * self.normal_B
