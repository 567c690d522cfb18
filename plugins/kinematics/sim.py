"""The ``sim`` kinematics: the simulated robot's flange pose from the session's world.

Samples come at ``rate_hz`` from the time the source is opened, like the ``sim``
sensor: sample i at ``t0_ns + round(i·1e9/rate_hz)`` ns, world time
``(t_ns − t0_ns)/1e9`` s, carrying ``quat_BE`` [w, x, y, z] and ``p_BoEo_B`` (m).
"""

from __future__ import annotations

from ...core import hookimpl
from ...core.frames import quat_wxyz_from_matrix
from ...core.plugins import ConfigError
from ...core.types import PoseSample
from ..simworld.physics import SampleClock, SimWorld


class SimKinematics:
    """Forward kinematics of the simulated robot (KinematicsSource).

    Parameters
    ----------
    rate_hz : sample rate, Hz (UR RTDE runs at 125 or 500 Hz).
    world : the session's SimWorld (provided by the host, shared with the ``sim`` sensor).
    """

    def __init__(self, rate_hz: float = 500.0, world: SimWorld | None = None):
        if world is None:
            raise ConfigError("kinematics sim: needs the session's simulated world; "
                              "add a [world] table to the session (or pass world=SimWorld(...))")
        if not rate_hz > 0:
            raise ConfigError(f"kinematics.rate_hz: must be > 0, got {rate_hz!r}")
        self.rate_hz = float(rate_hz)
        self.world = world
        self._clock = SampleClock(self.rate_hz)

    def open(self, t0_ns: int) -> None:
        """Start streaming: sample 0 is at ``t0_ns`` (world time 0)."""
        self._clock.start(t0_ns)

    def read(self, until_ns: int) -> list[PoseSample]:
        """Every pose not yet returned with time <= ``until_ns``, in time order."""
        seq, t_ns = self._clock.take(until_ns)
        if len(seq) == 0:
            return []
        R_BE, p_BoEo_B = self.world.pose((t_ns - self._clock.t0_ns) / 1e9)
        quat_BE = quat_wxyz_from_matrix(R_BE)
        quat_BE.setflags(write=False)  # rows are handed out as views
        p_BoEo_B.setflags(write=False)
        return [PoseSample(t_ns=t, quat_BE=quat, p_BoEo_B=p)
                for t, quat, p in zip(t_ns.tolist(), quat_BE, p_BoEo_B)]

    def close(self) -> None:
        """Stop streaming (nothing to release)."""
        self._clock.t0_ns = None


@hookimpl
def register_kinematics(register):
    """Register the simulated robot's kinematics as ``sim``."""
    register("sim", SimKinematics)
