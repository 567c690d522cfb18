"""A simulated world's sensor and kinematics streams as a CSV file (the import contract).

For offline tools (``compensate``, ``discrepancy``) and their tests and
benchmarks: one row per sensor sample at ``rate_hz``, the wrench as read
(noise, bias, drift, calibration error, saturation) and the pose as the
kinematics report it for the same stamp (so a ``kinematics_lag`` shows).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hapticlab.core.frames import quat_wxyz_from_matrix
from hapticlab.plugins.simworld.physics import SimWorld

HEADER = "t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz,px,py,pz"


def write_csv(world: SimWorld, path: str | Path, duration: float, rate_hz: float, positions: bool = True) -> np.ndarray:
    """Write ``duration`` s of ``world`` sampled at ``rate_hz`` to ``path``; returns the contact flag per row.

    Columns ``t,fx,fy,fz,tx,ty,tz,qw,qx,qy,qz`` and, with ``positions``, ``px,py,pz``.
    """
    t = np.arange(round(duration * rate_hz)) / rate_hz
    reading = world.wrench(t)
    R_BE, p_BoEo_B = world.pose(t)
    columns = [t[:, None], reading["force_S"], reading["torque_S"], quat_wxyz_from_matrix(R_BE)]
    header = HEADER if positions else HEADER.rsplit(",", 3)[0]
    if positions:
        columns.append(p_BoEo_B)
    np.savetxt(path, np.concatenate(columns, axis=1), delimiter=",", header=header, comments="", fmt="%.10g")
    return reading["contact"]
