"""The ``sim`` kinematics: the simulated robot's flange pose from the session's world.

Samples come at ``rate_hz`` from the time the source is opened, like the ``sim``
sensor: sample i at ``t0_ns + round(i·1e9/rate_hz)`` ns, world time
``(t_ns − t0_ns)/1e9`` s, carrying ``quat_BE`` [w, x, y, z] and ``p_BoEo_B`` (m).
"""

from __future__ import annotations

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.frames import quat_multiply, quat_wxyz_from_matrix
from hapticlab.core.host.options import number
from hapticlab.core.types import PoseSample
from hapticlab.plugins.kinematics import sim_kernel as pose_kernel
from hapticlab.plugins.kinematics.ur_arm import UR5E_FORCE_ACCURACY_N
from hapticlab.plugins.simworld.clock import SampleClock
from hapticlab.plugins.simworld.faults import kinematics_faults_act, kinematics_times
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.prefetch import PREFETCH_S, Prefetch
from hapticlab.plugins.simworld.randomness import gaussian_noise
from hapticlab.plugins.simworld.robot_wrench import WRENCH_NOISE_N, WRENCH_OFFSET_N, RobotWrench

ENCODER_STREAM = 2
"""The world's random stream of the robot's encoder jitter (0: sensor noise, 1: bias drift)."""
MAX_RATE_HZ = 10_000.0
"""Fastest kinematics stream accepted (an absurd rate would flood the loop)."""
MIN_RATE_HZ = 1.0
"""Slowest sample rate accepted: a period longer than a second is a typo (1e-300 Hz overflowed the aligner)."""


class SimKinematics:
    """Forward kinematics of the simulated robot (KinematicsSource), and its own wrench (MeasuresWrench).

    Parameters
    ----------
    rate_hz : sample rate, Hz (UR RTDE runs at 125 or 500 Hz).
    encoder_noise : standard deviation of the reported orientation (rad, per axis) and
        position (m, per axis) around the true pose. A real arm's reported pose is never
        bit-identical from one sample to the next, its encoders jitter; only a frozen
        controller repeats it exactly (which the session loop watches for). 0: the
        exact physics.
    wrench_accuracy, wrench_offset, wrench_noise : the robot's own measure of the contact wrench on its tool
        (``PoseSample.wrench_B``, as a UR e-Series reports): its stated force accuracy, largest offset and
        noise, N per axis (``simworld.robot_wrench.RobotWrench``; defaults 4.0, 1.5 and 0.6 N: a UR5e's).
        ``wrench_accuracy = 0``: the poses carry no wrench.
    world : the session's SimWorld (provided by the host, shared with the ``sim`` sensor).
    """

    def __init__(
        self,
        rate_hz: float = 500.0,
        encoder_noise: float = 1e-7,
        world: SimWorld | None = None,
        wrench_accuracy: float = UR5E_FORCE_ACCURACY_N,
        wrench_offset: float = WRENCH_OFFSET_N,
        wrench_noise: float = WRENCH_NOISE_N,
    ):
        if world is None:
            raise ConfigError(
                "kinematics sim: needs the session's simulated world; "
                "add a [world] table to the session (or pass world=SimWorld(...))"
            )
        rate_hz = number("rate_hz", rate_hz, minimum=MIN_RATE_HZ, maximum=MAX_RATE_HZ, hint=" Hz")
        self.encoder_noise = number("encoder_noise", encoder_noise, minimum=0, maximum=1e-3, hint=" (rad and m)")
        self._noise_key = int(
            np.random.SeedSequence(world.seed, spawn_key=(ENCODER_STREAM,)).generate_state(1, np.uint64)[0]
        )
        self.rate_hz = float(rate_hz)
        self.world = world
        self.robot_wrench = RobotWrench(world, wrench_accuracy, wrench_offset, wrench_noise)
        self.wrench_accuracy_N = self.robot_wrench.accuracy
        """The stated accuracy of the poses' ``wrench_B``, N per axis (MeasuresWrench; 0: none)."""
        self._clock = SampleClock(self.rate_hz)
        self._ahead = Prefetch(self._exact_poses, self.rate_hz, ahead_s=0.0 if world.live else PREFETCH_S)
        self._noise_ahead = Prefetch(self._noise, self.rate_hz) if world.live else None
        """A live world's poses come one at a time; their encoder jitter and wrench noise (functions of the
        reading's time alone) ahead."""
        if world.live:
            pose_kernel.warm_up()  # compiled (or loaded from the cache) before the first live tick

    def open(self, t0_ns: int) -> None:
        """Start streaming: sample 0 is at ``t0_ns`` (world time 0)."""
        self._clock.start(t0_ns)
        self._ahead.reset()
        if self._noise_ahead is not None:
            self._noise_ahead.reset()

    def _noise(self, seq: np.ndarray) -> dict[str, np.ndarray]:
        """The encoder jitter and the wrench's noise of samples ``seq``, (N, 6) each (:meth:`_jitter`,
        ``RobotWrench.noise_at``)."""
        reading_ns = self._clock.times(seq) - self._clock.t0_ns
        noise = self.robot_wrench.noise_at(reading_ns) if self.robot_wrench.noise > 0 else np.zeros((len(seq), 6))
        return {"jitter": self._jitter(reading_ns, len(seq)), "wrench": noise}

    def _exact_poses(self, seq: np.ndarray) -> dict[str, np.ndarray]:
        """The poses of samples ``seq`` when no fault is injected (each reports its own time's pose)."""
        reading_ns = self._clock.times(seq) - self._clock.t0_ns
        jitter = noise = None
        if self._noise_ahead is not None:  # (copies: the compiled quaternion takes writable arrays)
            jitter, noise = self._noise_ahead.copies(int(seq[0]), int(seq[-1]) + 1)
        quat_BE, p_BoEo_B = self._poses(reading_ns / 1e9, reading_ns, jitter)
        wrench_B = self._wrenches(reading_ns / 1e9, reading_ns, noise)
        return {"quat_BE": quat_BE, "p_BoEo_B": p_BoEo_B, "wrench_B": wrench_B}

    def _wrenches(self, t: np.ndarray, reading_ns: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        """(N, 6) the robot's wrench at world times ``t`` (s) read at ``reading_ns`` (ns); (N, 0) without one.
        ``noise``: its noise at those readings, when already computed."""
        if self.wrench_accuracy_N > 0:
            return self.robot_wrench.measured(t, reading_ns, noise)
        return np.zeros((len(t), 0))

    def _poses(
        self, t: np.ndarray, reading_ns: np.ndarray, jitter: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``quat_BE`` (N, 4) and ``p_BoEo_B`` (N, 3) m reported: the pose at world times ``t`` (s) with the
        encoder jitter of the readings taken at world times ``reading_ns`` (ns) (``jitter``, when already
        computed). A live world's poses come one at a time: their quaternions are compiled
        (``plugins.kinematics.sim_kernel``; :meth:`_poses_reference` is the numpy the others take, in chunks)."""
        if not self.world.live:
            return self._poses_reference(t, reading_ns)
        R_BE, p_BoEo_B = self.world.pose(t)
        if jitter is None:
            jitter = self._jitter(reading_ns, len(t))
        quat_BE = np.empty((len(t), 4))
        pose_kernel.reported_quat(R_BE, jitter[:, :3], self.encoder_noise > 0, quat_BE)
        return quat_BE, (p_BoEo_B + jitter[:, 3:] if self.encoder_noise > 0 else p_BoEo_B)

    def _jitter(self, reading_ns: np.ndarray, n: int) -> np.ndarray:
        """(n, 6): each pose's small rotation δ (rad) and offset (m), a function of its stamp (zeros without
        encoder noise)."""
        if self.encoder_noise > 0:
            return gaussian_noise(self._noise_key, reading_ns, 6) * self.encoder_noise
        return np.zeros((n, 6))

    def _poses_reference(self, t: np.ndarray, reading_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_poses` in numpy."""
        R_BE, p_BoEo_B = self.world.pose(t)
        quat_BE = quat_wxyz_from_matrix(R_BE)
        if self.encoder_noise > 0:
            jitter = self._jitter(reading_ns, len(t))
            quat_BE = quat_BE + 0.5 * quat_multiply(quat_BE, np.column_stack([np.zeros(len(t)), jitter[:, :3]]))
            quat_BE /= np.linalg.norm(quat_BE, axis=1)[:, None]
            p_BoEo_B = p_BoEo_B + jitter[:, 3:]
        return quat_BE, p_BoEo_B

    def read(self, until_ns: int) -> list[PoseSample]:
        """Every pose not yet returned with time <= ``until_ns``, in time order."""
        seq, t_ns = self._clock.take(until_ns)
        if not seq:
            return []
        faults = self.world.faults
        t = (np.array(t_ns) - self._clock.t0_ns) / 1e9 if faults else None
        if t is not None and kinematics_faults_act(
            faults, t
        ):  # injected ([[world.faults]]): frozen, late or missing poses
            t, t_reading, keep = kinematics_times(faults, t)
            t_ns, t = [t_ns[k] for k in np.flatnonzero(keep)], t[keep]
            if len(t_ns) == 0:
                return []
            reading_ns = np.round(t_reading[keep] * 1e9).astype(np.int64)
            quat_BE, p_BoEo_B = self._poses(t, reading_ns)
            wrench_B = self._wrenches(t, reading_ns)
            for array in (quat_BE, p_BoEo_B, wrench_B):
                array.setflags(write=False)  # rows are handed out as views
        else:
            poses = self._ahead.take(seq.start, seq.stop)  # read-only views
            quat_BE, p_BoEo_B, wrench_B = poses["quat_BE"], poses["p_BoEo_B"], poses["wrench_B"]
        if wrench_B.shape[1] == 0:
            return [PoseSample(t_ns=t, quat_BE=quat, p_BoEo_B=p) for t, quat, p in zip(t_ns, quat_BE, p_BoEo_B)]
        return [
            PoseSample(t_ns=t, quat_BE=quat, p_BoEo_B=p, wrench_B=w)
            for t, quat, p, w in zip(t_ns, quat_BE, p_BoEo_B, wrench_B)
        ]

    def prepare(self, until_ns: int) -> None:
        """Compute the readings up to ``until_ns`` now, if they are not yet (PreparesAhead; with a live world
        only their jitter and noise)."""
        lo, hi = self._clock.next_index, self._clock.end_index(until_ns)
        self._ahead.prepare(lo, hi)
        if self._noise_ahead is not None:
            self._noise_ahead.prepare(lo, hi)

    def close(self) -> None:
        """Stop streaming (nothing to release)."""
        self._clock.t0_ns = None


class ServoedSimKinematics(SimKinematics):
    """The simulated robot of a world whose motion is ``servo``: it also follows targets (ServosCartesian)."""

    def servo_cp(self, t_ns: int, R_BE: np.ndarray, p_BoEo_B: np.ndarray) -> None:
        """Follow the flange pose ``R_BE`` (3, 3), ``p_BoEo_B`` (3,) m from session time ``t_ns`` on."""
        if self._clock.t0_ns is None:
            raise RuntimeError("servo_cp before open()")
        self.world.servo_cp((t_ns - self._clock.t0_ns) / 1e9, R_BE, p_BoEo_B)


def sim_kinematics(
    rate_hz: float = 500.0,
    encoder_noise: float = 1e-7,
    world: SimWorld | None = None,
    wrench_accuracy: float = UR5E_FORCE_ACCURACY_N,
    wrench_offset: float = WRENCH_OFFSET_N,
    wrench_noise: float = WRENCH_NOISE_N,
) -> SimKinematics:
    """The ``sim`` kinematics (options as :class:`SimKinematics`): one that follows targets when the world's
    motion is ``servo`` (:class:`ServoedSimKinematics`), else one that reports the scripted motion."""
    factory = ServoedSimKinematics if world is not None and world.live else SimKinematics
    return factory(rate_hz, encoder_noise, world, wrench_accuracy, wrench_offset, wrench_noise)


@hookimpl
def register_kinematics(register):
    """Register the simulated robot's kinematics as ``sim``."""
    register("sim", sim_kinematics)
