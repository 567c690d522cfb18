"""Small records passed between the stages of a session.

Timestamps are integer nanoseconds on one monotonic clock (``*_ns``), the same
clock MCAP uses as log time. Forces are in N, torques in N·m, positions in m.
Frames follow Drake's monogram notation (see ``hapticlab.core.frames``): a
field named ``force_S`` is expressed in the sensor frame S, ``R_EB`` maps
vectors from B into E.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import MISSING, dataclass, field, fields
from typing import Any, TypeVar, cast, dataclass_transform

import numpy as np

_Record = TypeVar("_Record")


@dataclass_transform(frozen_default=True)
def record(cls: type[_Record]) -> type[_Record]:
    """``@dataclass(frozen=True, slots=True)``, with an ``__init__`` that sets each field through its slot.

    Quicker than the dataclass's own (``object.__setattr__`` per field), and every tick builds several records.
    Nothing else changes: the same arguments and defaults; assigning a field raises ``FrozenInstanceError``;
    equality, ``repr``, ``replace`` and pickling are the dataclass's. Fields need plain defaults (no factory).
    """
    cls = dataclass(frozen=True, slots=True)(cls)
    record_fields = fields(cast(Any, cls))  # a dataclass: the line above made it one
    names = [f.name for f in record_fields]
    namespace: dict[str, Any] = {f"_set_{name}": getattr(cls, name).__set__ for name in names}
    params = []
    for f in record_fields:
        if f.default_factory is not MISSING:
            raise TypeError(f"record {cls.__name__}.{f.name}: a default_factory needs the dataclass's own __init__")
        if f.default is MISSING:
            params.append(f.name)
        else:
            namespace[f"_default_{f.name}"] = f.default
            params.append(f"{f.name}=_default_{f.name}")
    body = "".join(f"    _set_{name}(self, {name})\n" for name in names)
    exec(f"def __init__(self, {', '.join(params)}):\n{body}", namespace)  # as dataclasses builds its own
    init = namespace["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__annotations__ = dict(cls.__init__.__annotations__)
    cls.__init__ = init  # type: ignore[method-assign]  # replacing the dataclass's __init__ is the point
    return cls


# Status bits of a WrenchSample. 0 means a good reading.
STATUS_OK = 0
STATUS_SATURATED = 1 << 0
STATUS_DEVICE_ERROR = 1 << 1


@record
class WrenchSample:
    """One raw reading of a six-axis force/torque sensor.

    Attributes:
        t_ns: time of the reading, ns, monotonic session clock.
        force_S: (3,) raw force in the sensor frame S, N.
        torque_S: (3,) raw torque in S about the sensor origin, N·m.
        seq: the device's sequence number (NetFT RDT sequence, or a counter).
        status: device status bits, ``STATUS_OK`` (0) when the reading is good.
    """

    t_ns: int
    force_S: np.ndarray
    torque_S: np.ndarray
    seq: int = 0
    status: int = STATUS_OK


@record
class WrenchBlock:
    """Raw readings of a six-axis force/torque sensor, as arrays: what a sensor that ``ReadsBlocks``
    hands over, and what the loop makes of any other sensor's list of :class:`WrenchSample`.

    Attributes:
        t_ns: (N,) int64 times of the readings, ns, monotonic session clock.
        force_S: (N, 3) raw force in the sensor frame S, N.
        torque_S: (N, 3) raw torque in S about the sensor origin, N·m.
        seq: (N,) int64 the device's sequence numbers.
        status: (N,) int64 device status bits, ``STATUS_OK`` (0) where a reading is good.
    """

    t_ns: np.ndarray
    force_S: np.ndarray
    torque_S: np.ndarray
    seq: np.ndarray
    status: np.ndarray

    def __len__(self) -> int:
        return len(self.t_ns)

    @classmethod
    def from_samples(cls, samples: list[WrenchSample]) -> WrenchBlock:
        """The readings of ``samples`` (in their order) as arrays."""
        n = len(samples)
        return cls(
            np.array([w.t_ns for w in samples], dtype=np.int64).reshape(n),
            np.array([w.force_S for w in samples], dtype=float).reshape(n, 3),
            np.array([w.torque_S for w in samples], dtype=float).reshape(n, 3),
            np.array([w.seq for w in samples], dtype=np.int64).reshape(n),
            np.array([w.status for w in samples], dtype=np.int64).reshape(n),
        )

    @classmethod
    def concatenate(cls, blocks: list[WrenchBlock]) -> WrenchBlock:
        """One block of ``blocks``' readings, in their order (at least one block)."""
        if len(blocks) == 1:
            return blocks[0]
        return cls(
            *(
                np.concatenate(arrays)
                for arrays in zip(*((b.t_ns, b.force_S, b.torque_S, b.seq, b.status) for b in blocks))
            )
        )

    def subset(self, index: slice | np.ndarray) -> WrenchBlock:
        """The readings selected by a slice, a boolean mask or an index array."""
        return WrenchBlock(
            self.t_ns[index], self.force_S[index], self.torque_S[index], self.seq[index], self.status[index]
        )

    def split(self, until_ns: int) -> tuple[WrenchBlock, WrenchBlock]:
        """(the readings due by ``until_ns``, the rest): what a sensor hands over now and what it keeps."""
        if not len(self) or self.t_ns[0] > until_ns:
            return NO_WRENCHES, self
        if self.t_ns[-1] <= until_ns:
            return self, NO_WRENCHES
        cut = int(np.argmax(self.t_ns > until_ns))  # the first reading not yet due
        return self.subset(slice(0, cut)), self.subset(slice(cut, None))

    def samples(self) -> list[WrenchSample]:
        """The readings one record each (rows of ``force_S``/``torque_S`` as read-only views: a record's
        reading cannot be changed; the block's own arrays stay as they are)."""
        force_S, torque_S = self.force_S.view(), self.torque_S.view()
        force_S.setflags(write=False)
        torque_S.setflags(write=False)
        return [
            WrenchSample(t_ns=t, force_S=force, torque_S=torque, seq=i, status=status)
            for t, force, torque, i, status in zip(
                self.t_ns.tolist(), force_S, torque_S, self.seq.tolist(), self.status.tolist()
            )
        ]


NO_WRENCHES = WrenchBlock(
    np.zeros(0, dtype=np.int64),
    np.zeros((0, 3)),
    np.zeros((0, 3)),
    np.zeros(0, dtype=np.int64),
    np.zeros(0, dtype=np.int64),
)
"""The empty block: what a sensor that ``ReadsBlocks`` returns when nothing is new."""


@record
class PoseSample:
    """One forward-kinematics reading of the robot end (flange) frame E.

    Attributes:
        t_ns: time of the reading, ns, monotonic session clock.
        quat_BE: (4,) unit quaternion [w, x, y, z] of R_BE, the orientation of E in B.
        p_BoEo_B: (3,) position of E's origin from B's origin, in B, m; None if unknown.
        joints: (n,) joint positions, rad (CRTK ``measured_js`` position); None if unknown.
        joint_velocities: (n,) joint velocities, rad/s (``measured_js`` velocity); None if unknown.
        w_BE_E: (3,) angular velocity of E in B, expressed in E, rad/s; None if the source does not
            compute it (``urdf`` does, from the joint velocities).
        alpha_BE_E: (3,) angular acceleration of E in B, expressed in E, rad/s²; None if unknown.
        a_BEo_B: (3,) translational acceleration of E's origin in B, expressed in B, m/s² (gravity
            not included); None if unknown.
        wrench_B: (6,) the robot's own measure of the contact wrench on its tool (CRTK ``measured_cf``), in B:
            force, N, then moment about the TCP, N·m; None if the source reports none (``MeasuresWrench``).

    The last three are what ``plugins.estimators.kalman.derivatives.MotionDerivatives`` estimates from the poses
    (its ``w_E``, ``alpha_E``, ``a_B``), for a tool's inertial wrench; a source that knows them
    from the joints fills them in. No estimator reads them yet: the aligner carries poses only.
    """

    t_ns: int
    quat_BE: np.ndarray
    p_BoEo_B: np.ndarray | None = None
    joints: np.ndarray | None = None
    joint_velocities: np.ndarray | None = None
    w_BE_E: np.ndarray | None = None
    alpha_BE_E: np.ndarray | None = None
    a_BEo_B: np.ndarray | None = None
    wrench_B: np.ndarray | None = None


@record
class AlignedSamples:
    """A block of wrench samples, each paired with the orientation at its own time.

    Arrays rather than one record per sample: the aligner interpolates a whole
    block at once (one scipy Slerp call), the estimator then walks the rows.

    Attributes:
        t_ns: (N,) int64 sample times, ns.
        force_S: (N, 3) raw force in S, N.
        torque_S: (N, 3) raw torque in S, N·m.
        R_EB: (N, 3, 3) orientation of B in E at each sample time (so ``v_E = R_EB @ v_B``).
        seq: (N,) sensor sequence numbers.
        status: (N,) sensor status bits.
        stale: (N,) True where the orientation had to be held longer than one
            kinematics period past the last pose (never silently extrapolated).
        quat_BE: (N, 4) the same orientations as [w, x, y, z] quaternions of E
            in B, when the producer has them (None otherwise).
        p_BoEo_B: (N, 3) position of E's origin in B at each sample time, m,
            when the kinematics stream has positions (None otherwise).
    """

    t_ns: np.ndarray
    force_S: np.ndarray
    torque_S: np.ndarray
    R_EB: np.ndarray
    seq: np.ndarray
    status: np.ndarray
    stale: np.ndarray
    quat_BE: np.ndarray | None = None
    p_BoEo_B: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def usable(self) -> np.ndarray:
        """(N,) samples an estimator may see: orientation not stale, status good, wrench and pose finite."""
        ok: np.ndarray = (
            ~self.stale
            & (self.status == STATUS_OK)
            & np.isfinite(self.force_S).all(1)
            & np.isfinite(self.torque_S).all(1)
            & np.isfinite(self.R_EB).all(axis=(1, 2))
        )
        if self.p_BoEo_B is not None:
            ok &= np.isfinite(self.p_BoEo_B).all(1)
        return ok

    def subset(self, index: slice | np.ndarray) -> AlignedSamples:
        """The samples selected by a boolean mask or index array."""
        return AlignedSamples(
            self.t_ns[index],
            self.force_S[index],
            self.torque_S[index],
            self.R_EB[index],
            self.seq[index],
            self.status[index],
            self.stale[index],
            None if self.quat_BE is None else self.quat_BE[index],
            None if self.p_BoEo_B is None else self.p_BoEo_B[index],
        )


@record
class Estimates:
    """An estimator's output for a block of samples, one row per sample.

    Attributes:
        t_ns: (m,) times of the samples, ns.
        contact_force_S: (m, 3) estimated tool–tissue contact force in S, N.
        contact_torque_S: (m, 3) estimated contact torque in S, N·m.
        contact: (m,) True where the estimator judged the sample to be contact.
        converged_force: (m,) the force stage had converged after the sample.
        converged_torque: (m,) the torque stage had converged after the sample.
        params: identified parameters after the block's last sample, by
            physical name (``gravity_force_B``, ``bias_force_S``, ``cog_S``,
            ``bias_torque_S``, ...), SI units; None when not attached (the
            estimator's ``params()`` gives them on demand).
        cov_diag: diagonal of the state covariance after the last sample, or None.
    """

    t_ns: np.ndarray
    contact_force_S: np.ndarray
    contact_torque_S: np.ndarray
    contact: np.ndarray
    converged_force: np.ndarray
    converged_torque: np.ndarray
    params: dict[str, list[float]] | None = None
    cov_diag: list[float] | None = None

    def __len__(self) -> int:
        return len(self.t_ns)

    @classmethod
    def concatenate(
        cls, parts: list[Estimates], params: dict[str, list[float]] | None = None, cov_diag: list[float] | None = None
    ) -> Estimates:
        """Consecutive blocks' estimates as one (``params``/``cov_diag`` describe the end)."""
        return cls(
            t_ns=np.concatenate([p.t_ns for p in parts]),
            contact_force_S=np.concatenate([p.contact_force_S for p in parts]),
            contact_torque_S=np.concatenate([p.contact_torque_S for p in parts]),
            contact=np.concatenate([p.contact for p in parts]),
            converged_force=np.concatenate([p.converged_force for p in parts]),
            converged_torque=np.concatenate([p.converged_torque for p in parts]),
            params=params,
            cov_diag=cov_diag,
        )


def first_true(flags: np.ndarray) -> int | None:
    """Index of the first True in a bool array (e.g. the sample a stage first converged at), or None."""
    return int(np.argmax(flags)) if flags.any() else None


@record
class HapticCommand:
    """A force command for the haptic master device.

    Attributes:
        t_ns: time the command was issued, ns.
        force_D: (3,) force on the handle in the device base frame D, N.
        enabled: False when the output is held at zero for safety.
        reason: why the output is disabled ("" when enabled).
        source_t_ns: stamp of the newest sensor sample behind the force, ns (None for a zero
            command): ``t_ns − source_t_ns`` is the estimate's age when it was commanded.
    """

    t_ns: int
    force_D: np.ndarray
    enabled: bool
    reason: str = ""
    source_t_ns: int | None = None


@record
class DeviceState:
    """State reported by a haptic master device.

    Attributes:
        t_ns: time of the report, ns.
        quat_DH: (4,) orientation [w, x, y, z] of the handle H in the device base D.
        p_DoHo_D: (3,) handle position in D, m (CRTK ``measured_cp``).
        buttons: bit mask of pressed buttons.
        v_DHo_D: (3,) translational velocity of the handle origin in D, expressed in D, m/s
            (CRTK ``measured_cv``); None when the device does not report it.
    """

    t_ns: int
    quat_DH: np.ndarray
    p_DoHo_D: np.ndarray
    buttons: int = 0
    v_DHo_D: np.ndarray | None = None


@record
class RobotTarget:
    """Where teleoperation sends the robot's flange E (CRTK ``servo_cp``), one per loop tick.

    Attributes:
        t_ns: time the target was sent, ns.
        R_BE: (3, 3) target orientation of E in B.
        p_BoEo_B: (3,) target position of E's origin in B, m.
        mode: ``"calibrating"`` (the identification tour before the hand takes over),
            ``"following"`` (the handle drives the target) or ``"holding"`` (the target stays).
        reason: why it is holding ("" otherwise).
    """

    t_ns: int
    R_BE: np.ndarray
    p_BoEo_B: np.ndarray
    mode: str
    reason: str = ""


@dataclass(frozen=True, slots=True)
class Event:
    """Something a person reviewing the session should know about: when (``t_ns``, ns), a short machine-readable
    ``kind`` ("haptic_disabled", "converged", ...), one human-readable ``message`` line, and ``data`` (details
    for a program: SI units and frames in the key names; empty by default)."""

    t_ns: int
    kind: str
    message: str
    data: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class EmulatorCommand:
    """A device emulator as ``hapticlab emulate NAME`` runs it (what ``register_emulators`` registers).

    Attributes:
        help: one line for ``hapticlab emulate --help``.
        add_arguments: ``add_arguments(parser)`` adds its options to an ``argparse`` parser.
        run: ``run(args) -> int``, or ``run(args, world) -> int`` with ``needs_world``: serves until Ctrl-C,
            SIGTERM or ``--duration``, the first line printed saying where it listens; returns the exit status.
        needs_world: the emulator is fed by a simulated world. The host then adds ``--session`` (a preset name
            or TOML file, default ``session``) and ``--seed`` (overrides the world's seed) to its options, builds
            the session's world through the ``world`` context (``register_contexts``) and passes it to ``run``;
            an emulator never reads a session itself (a plugin does not import the sessions layer).
        session: the preset ``--session`` defaults to.
        listens_on: the options (argparse ``dest`` names) holding an address it listens on. The host adds
            ``--allow-network`` and, without it, refuses a non-loopback one (an emulated device answers anyone).
    """

    help: str
    add_arguments: Callable[[Any], None]
    run: Callable[..., int]
    needs_world: bool = False
    session: str = "demo"
    listens_on: tuple[str, ...] = ()

    def __call__(self, *args: Any) -> int:
        return self.run(*args)
