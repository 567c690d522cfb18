"""A cable, hose or trocar on the tool: a force that depends on where the tool is and how fast it moves.

Physical effects outside the discrepancy workflow's effect library (to test what it makes of them):
a sensor cable or an irrigation hose clipped to the tool pulls it towards where
the cable is held, more the further the tool moves away; an instrument passing
through a trocar or moving in fluid is dragged against its velocity. Both as one
linear spring–damper between the touching point ``x`` (in B) and an anchor::

    f_B = k·(anchor_B − x) − c·ẋ

k the stiffness (N/m; 0: drag only), c the damping (N·s/m; 0: spring only). It
acts all the time (it is not a contact a gate could set aside). A dressed F/T
cable is of the order of 5–20 N/m over a few centimetres; a trocar's drag of
1–5 N·s/m.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hapticlab.core.host.options import check, check_fields, number, vector


@dataclass(frozen=True, slots=True)
class Cable:
    """A linear spring–damper from an anchor in B to a point of the tool.

    Attributes:
        anchor_B: (3,) where the cable is held, in B, m.
        stiffness: k, the pull per metre from the anchor, N/m (>= 0; 0: drag only).
        damping: c, the drag per m/s of the point's velocity, N·s/m (>= 0; 0: spring only).
        point_S: (3,) the point of the tool it pulls, in S, m; None: the tool tip.
    """

    anchor_B: np.ndarray = (0.45, 0.0, 0.6)  # type: ignore[assignment]  # an array after __post_init__
    stiffness: float = 10.0
    damping: float = 0.0
    point_S: np.ndarray | None = None

    def __post_init__(self) -> None:
        check_fields(
            self,
            {
                "anchor_B": vector,
                "stiffness": check(number, minimum=0, hint=" (N/m)"),
                "damping": check(number, minimum=0, hint=" (N·s/m)"),
            },
        )
        if self.point_S is not None:
            object.__setattr__(self, "point_S", vector("point_S", self.point_S))

    def force_B_at(self, x_B: np.ndarray, v_B: np.ndarray) -> np.ndarray:
        """(N, 3) force of the cable on the tool, in B, N, for the point at ``x_B`` (N, 3) m moving at
        ``v_B`` (N, 3) m/s."""
        return self.stiffness * (self.anchor_B - x_B) - self.damping * v_B
