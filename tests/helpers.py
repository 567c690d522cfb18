"""Test helpers: seeded, physically generated data (no hand-made numbers)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.core.types import AlignedSamples

ROOT = Path(__file__).resolve().parents[1]
"""The repository (the hapticlab package's folder: docs/, firmware/, pyproject.toml); tests find its files from here."""
REAL_DATA = ROOT.parent / "shared" / "data" / "real"
"""The real recordings, beside the repository (the ``real_data`` fixture, tests/conftest.py)."""


def static_model_stream(
    n: int,
    seed: int,
    noise_force: float = 0.0,
    noise_torque: float = 0.0,
    gravity_force_B=(0.12, -0.25, -3.4),
    bias_force_S=(1.0, -0.5, 2.0),
    cog_S=(0.002, -0.001, 0.0435),
    bias_torque_S=(0.03, -0.02, 0.01),
):
    """Samples of the paper's static model (eqs. 16–17) at random orientations.

    Returns (AlignedSamples, truth dict). Orientations are uniformly random
    (strong excitation); noise is Gaussian per axis.
    """
    rng = np.random.default_rng(seed)
    R_EB = Rotation.random(n, random_state=seed).as_matrix().transpose(0, 2, 1)
    gravity_force_B = np.asarray(gravity_force_B, float)
    gravity_S = R_EB @ gravity_force_B
    force_S = gravity_S + bias_force_S + rng.normal(0, noise_force, (n, 3))
    torque_S = np.cross(cog_S, gravity_S) + bias_torque_S + rng.normal(0, noise_torque, (n, 3))
    block = AlignedSamples(
        t_ns=np.arange(n, dtype=np.int64) * 1_000_000,
        force_S=force_S,
        torque_S=torque_S,
        R_EB=R_EB,
        seq=np.arange(n),
        status=np.zeros(n, dtype=np.int64),
        stale=np.zeros(n, dtype=bool),
    )
    truth = {
        "gravity_force_B": gravity_force_B,
        "bias_force_S": np.asarray(bias_force_S, float),
        "cog_S": np.asarray(cog_S, float),
        "bias_torque_S": np.asarray(bias_torque_S, float),
    }
    return block, truth
