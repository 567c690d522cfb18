"""The paper's non-contact model (eqs. 18–19) and its contact wrench (eqs. 20–21).

    S_f   = R_EB · B_f + f0
    S_tau = p × (R_EB · B_f) + tau0

Every estimator of this model reports its state through these two functions,
so the contact wrench means the same thing whichever one produced it.
"""

from __future__ import annotations

import numpy as np

from .frames import cross


def contact_wrench(
    force_S: np.ndarray, torque_S: np.ndarray, R_EB: np.ndarray, x_force: np.ndarray, x_torque: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Contact force and torque in S per sample (eqs. 20–21).

    Args:
        force_S: (m, 3) raw force, N. torque_S: (m, 3) raw torque, N·m.
        R_EB: (m, 3, 3) orientation of B in E.
        x_force: (m, 6) [gravity_force_B, bias_force_S] per sample, N.
        x_torque: (m, 6) [cog_S (m), bias_torque_S (N·m)] per sample.

    Returns:
        (contact_force_S (m, 3) N, contact_torque_S (m, 3) N·m).
    """
    gravity_S = (R_EB @ x_force[:, :3, None])[:, :, 0]
    contact_force_S = force_S - gravity_S - x_force[:, 3:]
    contact_torque_S = torque_S - cross(x_torque[:, :3], gravity_S) - x_torque[:, 3:]
    return contact_force_S, contact_torque_S


def named_params(x_force: np.ndarray, x_torque: np.ndarray) -> dict[str, list[float]]:
    """The model's parameters by physical name (SI units) from the two stage states."""
    return {
        "gravity_force_B": x_force[:3].tolist(),
        "bias_force_S": x_force[3:].tolist(),
        "cog_S": x_torque[:3].tolist(),
        "bias_torque_S": x_torque[3:].tolist(),
    }
