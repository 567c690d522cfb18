"""The ``sim`` sensor: a six-axis F/T sensor reading the session's simulated world.

Samples come at ``rate_hz`` from the time the sensor is opened: sample i is at
``t0_ns + round(i·1e9/rate_hz)`` ns, world time ``(t_ns − t0_ns)/1e9`` s, with
``seq = i`` and ``status`` STATUS_SATURATED where the reading was clipped. The
noise is a function of the sample time, so reading in chunks gives exactly the
samples one big read would.
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.host.options import number
from hapticlab.core.types import NO_WRENCHES, WrenchBlock, WrenchSample
from hapticlab.plugins.simworld.clock import SampleClock
from hapticlab.plugins.simworld.faults import apply_sensor_faults
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.prefetch import PREFETCH_S, Prefetch

MAX_RATE_HZ = 100_000.0
"""Fastest sample rate accepted (a Net F/T streams at up to 7 kHz; an absurd rate would flood the loop)."""
MIN_RATE_HZ = 1.0
"""Slowest sample rate accepted: a period longer than a second is a typo (1e-300 Hz overflowed the aligner)."""


class SimSensor:
    """A simulated F/T sensor (SensorSource, ReadsBlocks).

    The loop reads it with :meth:`read_block` (arrays, no record per sample); :meth:`read` is built from
    it, so a subclass that changes what the sensor delivers overrides :meth:`read_block`.

    Parameters
    ----------
    rate_hz : sample rate, Hz.
    world : the session's SimWorld (provided by the host, shared with the ``sim``
        kinematics).
    """

    def __init__(self, rate_hz: float = 1000.0, world: SimWorld | None = None):
        if world is None:
            raise ConfigError(
                "sensor sim: needs the session's simulated world; "
                "add a [world] table to the session (or pass world=SimWorld(...))"
            )
        self.rate_hz = number("rate_hz", rate_hz, minimum=MIN_RATE_HZ, maximum=MAX_RATE_HZ, hint=" Hz")
        self.world = world
        self.range_force_S = world.sensor.saturation_force_S.copy()
        """(3,) measurement range per force axis, N (HasRange): the sensor saturates beyond it."""
        self.range_torque_S = world.sensor.saturation_torque_S.copy()
        """(3,) measurement range per torque axis, N·m."""
        self._clock = SampleClock(self.rate_hz)
        self._ahead = Prefetch(self._reading, self.rate_hz, ahead_s=0.0 if world.live else PREFETCH_S)
        self._channels_ahead = Prefetch(self._channels, self.rate_hz) if world.live else None
        """A live world's readings come one at a time; their bias and noise (functions of time alone) ahead."""

    def open(self, t0_ns: int) -> None:
        """Start streaming: sample 0 is at ``t0_ns`` (world time 0)."""
        self._clock.start(t0_ns)
        self._ahead.reset()
        if self._channels_ahead is not None:
            self._channels_ahead.reset()

    def _channels(self, seq: np.ndarray) -> dict[str, np.ndarray]:
        """The channels' bias and noise, (N, 6) each, at the samples ``seq`` (``SensorChannels.read``)."""
        t = (self._clock.times(seq) - self._clock.t0_ns) / 1e9
        return {"bias_S": self.world.channels.bias(t), "noise_S": self.world.channels.noise(t)}

    def _reading(self, seq: np.ndarray) -> dict[str, np.ndarray]:
        """What the sensor reads for the samples ``seq`` (the world's physics, before any injected fault):
        :class:`WrenchBlock`'s fields, in its order."""
        t_ns = self._clock.times(seq)
        known = None
        if self._channels_ahead is not None:
            channels = self._channels_ahead.take(int(seq[0]), int(seq[-1]) + 1)
            known = (channels["bias_S"], channels["noise_S"])
        reading = self.world.wrench((t_ns - self._clock.t0_ns) / 1e9, known=known, truth=False)
        return {
            "t_ns": t_ns,
            "force_S": reading["force_S"],
            "torque_S": reading["torque_S"],
            "seq": seq,
            "status": reading["status"].astype(np.int64, copy=False),
        }

    def read(self, until_ns: int) -> list[WrenchSample]:
        """Every sample not yet returned with time <= ``until_ns``, in time order (read-only arrays)."""
        return self.read_block(until_ns).samples()

    def read_block(self, until_ns: int) -> WrenchBlock:
        """:meth:`read` as arrays (ReadsBlocks): the loop's way in, no record per sample. The arrays are
        the block's own (copied from the computed chunk, which stays read-only)."""
        seq = self._clock.advance(until_ns)
        if not seq:
            return NO_WRENCHES
        if self._channels_ahead is None:
            t_ns, force_S, torque_S, numbers, status = self._ahead.copies(seq.start, seq.stop)
        else:  # a live world's samples, computed now for this read alone: no chunk to copy from
            reading = self._reading(np.arange(seq.start, seq.stop, dtype=np.int64))
            t_ns, numbers, status = reading["t_ns"], reading["seq"], reading["status"]
            force_S, torque_S = np.ascontiguousarray(reading["force_S"]), np.ascontiguousarray(reading["torque_S"])
        if self.world.faults:  # injected faults ([[world.faults]]): what the sensor delivers, not the physics
            reading = {"force_S": force_S, "torque_S": torque_S, "status": status}  # changed in place
            keep = apply_sensor_faults(self.world.faults, (t_ns - self._clock.t0_ns) / 1e9, reading)
            if not keep.all():
                t_ns, force_S, torque_S, numbers, status = (a[keep] for a in (t_ns, force_S, torque_S, numbers, status))
        return WrenchBlock(t_ns, force_S, torque_S, numbers, status)

    def prepare(self, until_ns: int) -> None:
        """Compute the readings up to ``until_ns`` now, if they are not yet (PreparesAhead; with a live world
        only the channels' bias and noise)."""
        lo, hi = self._clock.next_index, self._clock.end_index(until_ns)
        self._ahead.prepare(lo, hi)
        if self._channels_ahead is not None:
            self._channels_ahead.prepare(lo, hi)

    def close(self) -> None:
        """Stop streaming (nothing to release)."""
        self._clock.t0_ns = None


@hookimpl
def register_sensors(register):
    """Register the simulated sensor as ``sim``."""
    register("sim", SimSensor)
