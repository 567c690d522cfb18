"""The simulated robot's own wrench measurement: a second channel beside the wrist sensor.

A UR e-Series arm reports the wrench on its tool over RTDE (``actual_TCP_force``),
measured at its flange, with the payload's weight taken out by the controller:
coarse, but independent of the wrist sensor and of hapticlab's estimators. The
simulated robot (``sim`` kinematics) and the UR emulator report the world's true
contact wrench (``SimWorld.contact_wrench_B``) plus the error modelled here: a
per-session offset and white noise, both functions of the world's seed and the
reading time, so a stream is the same whoever asks for it and when.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core.host.options import number
from hapticlab.plugins.kinematics.ur_arm import UR5E_FORCE_ACCURACY_N
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.randomness import gaussian_noise

ROBOT_WRENCH_STREAM = 4
"""The world's random stream of the robot's wrench error (0 sensor noise, 1 drift, 2 encoders and motion)."""
WRENCH_OFFSET_N = 1.5
"""The largest force offset per axis the simulated robot draws for a session, N (a real arm's zero wanders
between zeroings)."""
WRENCH_NOISE_N = 0.6
"""The simulated robot's force noise, N per axis (1σ): offset + 4σ = 3.9 N stays within the UR5e's 4 N."""
TORQUE_PER_FORCE_M = 0.075
"""The torque's error per newton of the force's, m (the UR5e's torque accuracy, 0.3 N·m, over its force's)."""


class RobotWrench:
    """What the simulated robot reports of the wrench on its tool, (N, 6) in B: force (N), moment about E (N·m).

    Parameters
    ----------
    world : the session's world (its contacts, motion and seed).
    accuracy : the stated force accuracy, N per axis: what the session's cross-check allows between the two
        channels (default the UR5e's 4.0 N). 0: the robot reports no wrench.
    offset : the largest force offset per axis, N: each session draws one in ±offset per axis (default 1.5 N:
        a real arm's zero wanders between zeroings).
    noise : white noise of the force, N per axis (1σ; default 0.6 N). offset + 4σ = 3.9 N stays within the
        default accuracy, as a working arm's does.
    """

    def __init__(
        self,
        world: SimWorld,
        accuracy: float = UR5E_FORCE_ACCURACY_N,
        offset: float = WRENCH_OFFSET_N,
        noise: float = WRENCH_NOISE_N,
    ):
        self.world = world
        self.accuracy = number("wrench_accuracy", accuracy, minimum=0, maximum=1e3, hint=" N")
        self.offset = number("wrench_offset", offset, minimum=0, maximum=1e3, hint=" N")
        self.noise = number("wrench_noise", noise, minimum=0, maximum=1e3, hint=" N")
        seed = np.random.SeedSequence(world.seed, spawn_key=(ROBOT_WRENCH_STREAM,))
        draw = np.random.default_rng(seed).uniform(-1.0, 1.0, 6)
        self.offset_B = np.concatenate([draw[:3], TORQUE_PER_FORCE_M * draw[3:]]) * self.offset
        """(6,) this session's offset: force N, torque N·m."""
        self._noise_key = int(seed.generate_state(1, np.uint64)[0])
        self._noise_scale = self.noise * np.array(
            [1.0, 1.0, 1.0, TORQUE_PER_FORCE_M, TORQUE_PER_FORCE_M, TORQUE_PER_FORCE_M]
        )

    def measured(self, t: np.ndarray, reading_ns: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        """(N, 6) the wrench reported for world times ``t`` (s) by the readings stamped ``reading_ns`` (ns);
        ``noise``: :meth:`noise_at` those stamps, when already computed."""
        wrench_B = self.world.contact_wrench_B(t) + self.offset_B
        if self.noise > 0:
            wrench_B += self.noise_at(reading_ns) if noise is None else noise
        return wrench_B

    def noise_at(self, reading_ns: np.ndarray) -> np.ndarray:
        """(N, 6) the white noise of the readings stamped ``reading_ns`` (ns): force N, torque N·m."""
        return gaussian_noise(self._noise_key, np.asarray(reading_ns, dtype=np.int64), 6) * self._noise_scale
