"""The ``urdf`` kinematics: forward kinematics of a URDF model on Pinocchio, over another source's joint angles.

A robot's controller reports joint angles (CRTK ``measured_js``); this source
turns them into the pose of a chosen frame of a URDF model (``measured_cp``):
the flange, or a sensor frame when the URDF has one, together with that
frame's angular velocity, angular acceleration and linear acceleration (the
tool's inertial wrench needs them). The joint angles come from an inner
kinematics source named in its own table, e.g. a UR arm over RTDE::

    [kinematics]
    name = "urdf"
    urdf = "ur5e"            # a shipped model (plugins/kinematics/urdf/<name>.urdf) or a path to a .urdf
    frame = "tool0"          # the frame reported as E
    base = "base"            # the frame reported as B (fixed to the URDF's root)
    joints = { name = "ur_rtde", address = "192.168.1.10" }

The inner source's poses are replaced: ``quat_BE``/``p_BoEo_B`` become the FK
of its ``joints``, and the sample gains ``w_BE_E``, ``alpha_BE_E`` and
``a_BEo_B`` (``core.types.PoseSample``). ω comes from the measured joint
velocities (exact up to their noise: ω = J(q) q̇); the accelerations need q̈,
which no controller reports, so q̈ is fitted causally over the last
``acceleration_window_s`` of joint velocities (a line through the newest q̇;
from the joint angles when the source gives no velocities: a quadratic, which
also gives q̇). The fit lags: with a joint jerk j (rad/s³) q̈ is off by about
0.4·j·window_s (0.41 for a line over five readings, 0.48 for the quadratic);
the 10 ms default at 500 Hz and a hand-guided pace (j ≈ 20 rad/s³) gives
≈ 0.08 rad/s².

Pinocchio (``pip install 'hapticlab[urdf]'``) is imported only when this
source is built. The URDF's moving joints must be revolute or prismatic (one
angle each), in the order the inner source reports them.
"""

from __future__ import annotations

from collections import deque
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from hapticlab.core import hookimpl
from hapticlab.core.errors import ConfigError
from hapticlab.core.host.interfaces import EmitsEvents, KinematicsSource, ReportsHealth
from hapticlab.core.host.options import OptionError, number
from hapticlab.core.host.registry import Registry
from hapticlab.core.types import Event, PoseSample

SHIPPED = "urdf"
"""The package folder of the shipped URDF files (``plugins/kinematics/urdf/<name>.urdf``)."""


def shipped_models() -> list[str]:
    """Names of the URDF models shipped with hapticlab (``urdf = "<name>"``)."""
    folder = resources.files(__package__) / SHIPPED
    return sorted(p.name[: -len(".urdf")] for p in folder.iterdir() if p.name.endswith(".urdf"))


def _import_pinocchio():
    """The ``pinocchio`` module, or a one-line ConfigError saying how to install it."""
    try:
        import pinocchio
    except ImportError:
        raise ConfigError(
            "kinematics.name: the urdf kinematics needs Pinocchio; pip install 'hapticlab[urdf]'"
        ) from None
    return pinocchio


def _urdf_text(urdf: str) -> tuple[str, str]:
    """(URDF XML, where it came from) of a shipped model's name or a file path."""
    if urdf in shipped_models():
        return (resources.files(__package__) / SHIPPED / f"{urdf}.urdf").read_text(), f"shipped {urdf}"
    path = Path(urdf).expanduser()
    if not path.is_file():
        raise OptionError(
            "urdf", f"must be a shipped model ({', '.join(shipped_models())}) or a URDF file, got {urdf!r}"
        )
    try:
        return path.read_text(), str(path)
    except (OSError, UnicodeDecodeError) as exc:
        raise OptionError("urdf", f"cannot read {path}: {exc}") from None


class UrdfModel:
    """A URDF model's forward kinematics of one frame relative to another, on Pinocchio.

    Parameters
    ----------
    urdf : a shipped model's name (``shipped_models()``) or a path to a URDF file.
    frame : the frame whose motion is reported (E): a link or joint name of the URDF.
    base : the frame it is reported in (B); it must be fixed to the URDF's root link.

    Attributes: ``n_joints`` (the model's joint angles, in the URDF's order),
    ``joint_names``, ``source`` (where the URDF came from).
    """

    def __init__(self, urdf: str = "ur5e", frame: str = "tool0", base: str = "base"):
        pin = _import_pinocchio()
        xml, self.source = _urdf_text(urdf)
        try:
            model = pin.buildModelFromXML(xml)
        except (RuntimeError, ValueError) as exc:
            reason = (str(exc).strip() or type(exc).__name__).splitlines()[0]
            raise OptionError("urdf", f"{self.source} is not a URDF Pinocchio can read: {reason}") from None
        if model.nq != model.nv:
            raise OptionError(
                "urdf",
                f"{self.source} has joints with more angles than velocities "
                f"(continuous, floating or spherical: nq {model.nq}, nv {model.nv}); "
                f"only revolute and prismatic joints are supported",
            )
        names = sorted({f.name for f in model.frames})
        for key, name in (("frame", frame), ("base", base)):
            if not model.existFrame(name):
                raise OptionError(key, f"must be a frame of {self.source} ({', '.join(names)}), got {name!r}")
        self._pin, self.model, self.data = pin, model, model.createData()
        self.frame_id, self.base_id = model.getFrameId(frame), model.getFrameId(base)
        if model.frames[self.base_id].parentJoint != 0:
            raise OptionError(
                "base",
                f"must be a frame fixed to the URDF's root link, got {base!r}, which moves with joint "
                f"{model.names[model.frames[self.base_id].parentJoint]!r}",
            )
        self.frame, self.base = frame, base
        self.n_joints = model.nq
        self.joint_names = list(model.names[1:])
        pin.framesForwardKinematics(model, self.data, pin.neutral(model))
        X_WB = self.data.oMf[self.base_id]  # W: the URDF's root (Pinocchio's universe); constant
        self.R_BW = X_WB.rotation.T.copy()
        self.p_WoBo_W = X_WB.translation.copy()

    def pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(R_BE (3, 3), p_BoEo_B (3,) m)`` for joint angles ``q`` (n,) rad (m for prismatic joints)."""
        self._pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return self._placement()

    def _placement(self) -> tuple[np.ndarray, np.ndarray]:
        X_WE = self.data.oMf[self.frame_id]
        return self.R_BW @ X_WE.rotation, self.R_BW @ (X_WE.translation - self.p_WoBo_W)

    def quaternion(self, R: np.ndarray) -> np.ndarray:
        """(4,) unit quaternion [w, x, y, z], w ≥ 0, of a rotation matrix (Pinocchio's: a tenth of numpy's cost)."""
        x, y, z, w = self._pin.Quaternion(R).coeffs()
        return np.array([w, x, y, z]) if w >= 0 else np.array([-w, -x, -y, -z])

    def motion(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> tuple[np.ndarray, ...]:
        """The pose of E in B and its derivatives for joint angles, velocities and accelerations.

        Args:
            q: (n,) joint angles, rad. qd: (n,) joint velocities, rad/s. qdd: (n,) joint accelerations, rad/s².

        Returns:
            (R_BE (3, 3), p_BoEo_B (3,) m, w_BE_E (3,) rad/s, alpha_BE_E (3,) rad/s², a_BEo_B (3,) m/s²):
            the angular velocity and acceleration of E in B expressed in E, and the
            acceleration of E's origin in B expressed in B (B is fixed, so relative to B is
            relative to the URDF's root).
        """
        pin, model, data = self._pin, self.model, self.data
        pin.forwardKinematics(
            model, data, np.asarray(q, dtype=float), np.asarray(qd, dtype=float), np.asarray(qdd, dtype=float)
        )
        pin.updateFramePlacement(model, data, self.frame_id)
        R_BE, p_BoEo_B = self._placement()
        w_BE_E = pin.getFrameVelocity(model, data, self.frame_id, pin.LOCAL).angular
        alpha_BE_E = pin.getFrameAcceleration(model, data, self.frame_id, pin.LOCAL).angular
        a_W = pin.getFrameClassicalAcceleration(model, data, self.frame_id, pin.LOCAL_WORLD_ALIGNED).linear
        return R_BE, p_BoEo_B, w_BE_E.copy(), alpha_BE_E.copy(), self.R_BW @ a_W


class JointRates:
    """Causal joint velocities and accelerations, fitted over a sliding window of past readings.

    ``update(t_ns, q, qd)`` with each reading in time order returns ``(qd, qdd)``:
    with measured velocities ``qd`` it returns them and fits q̈ as the slope of a
    line through the newest (t, q̇) over the window (least squares, ≥ 2 readings);
    with ``qd`` None it fits q(t) ≈ q_k + q̇ s + ½ q̈ s² (≥ 3 readings). Before enough
    readings have arrived the unknowns are None. Readings that are not finite are left
    out of every window (and give None themselves).

    Args:
        window_s: the fitting window, s; the readings needed for a fit are always used,
            however far apart.
    """

    def __init__(self, window_s: float = 0.01):
        self.window_ns = round(window_s * 1e9)
        self._history: deque[tuple[int, np.ndarray, np.ndarray | None]] = deque()

    def update(self, t_ns: int, q: np.ndarray, qd: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(q̇ (n,) rad/s or None, q̈ (n,) rad/s² or None) at the reading ``t_ns`` (ns), ``q`` (n,) rad."""
        if not (np.isfinite(q).all() and (qd is None or np.isfinite(qd).all())):
            return qd, None
        needed = 1 if qd is not None else 2  # past readings for a line through the newest, or a quadratic
        history = self._history
        while len(history) > needed and t_ns - history[0][0] > self.window_ns:
            history.popleft()  # older than the window, and enough readings are left without it
        past = [(t, q_i, qd_i) for t, q_i, qd_i in history if t < t_ns and (qd is None or qd_i is not None)]
        history.append((t_ns, np.array(q, dtype=float), None if qd is None else np.array(qd, dtype=float)))
        if len(past) < needed:
            return qd, None
        s = np.array([(t - t_ns) * 1e-9 for t, _, _ in past])  # s_i < 0, s
        if qd is not None:
            return qd, s @ (np.array([qd_i for _, _, qd_i in past]) - qd) / (s @ s)
        # least squares of Δq_i ≈ q̇ s_i + q̈ s_i²/2: the 2×2 normal equations, solved in closed form
        h = 0.5 * s * s
        dq = np.array([q_i for _, q_i, _ in past]) - q
        ss, sh, hh = s @ s, s @ h, h @ h
        det = ss * hh - sh * sh
        return (hh * (s @ dq) - sh * (h @ dq)) / det, (ss * (h @ dq) - sh * (s @ dq)) / det


class UrdfKinematics:
    """A URDF model's FK over an inner source's joint angles (KinematicsSource, EmitsEvents, ReportsHealth).

    Each of the inner source's poses is replaced by the URDF's: ``quat_BE`` and
    ``p_BoEo_B`` of ``frame`` in ``base``, with ``w_BE_E``, ``alpha_BE_E``,
    ``a_BEo_B``; ``t_ns``, ``joints`` and ``joint_velocities`` are kept. The
    inner source's events and health counters pass through.

    Parameters
    ----------
    joints : the inner source (any KinematicsSource whose poses carry ``joints``, rad,
        in the URDF's joint order; ``joint_velocities``, rad/s, when it has them).
    model : the URDF model and its frames E and B, e.g. ``UrdfModel("ur5e", frame="tool0")``.
    acceleration_window_s : the window of ``JointRates``, s (10 ms: five readings at 500 Hz).
    """

    def __init__(self, joints: KinematicsSource, model: UrdfModel, acceleration_window_s: float = 0.01):
        _check_window(acceleration_window_s)
        self.model = model
        self.inner = joints
        self.rate_hz = float(joints.rate_hz)
        self.acceleration_window_s = float(acceleration_window_s)
        self._inner_events = joints if isinstance(joints, EmitsEvents) else None
        self._inner_health = joints if isinstance(joints, ReportsHealth) else None
        self._rates = JointRates(self.acceleration_window_s)

    def open(self, t0_ns: int) -> None:
        """Open the inner source (its clock starts at ``t0_ns``)."""
        self._rates = JointRates(self.acceleration_window_s)
        self.inner.open(t0_ns)

    def read(self, until_ns: int) -> list[PoseSample]:
        """The inner source's readings up to ``until_ns``, each with the URDF frame's pose and motion."""
        return [self._forward(sample) for sample in self.inner.read(until_ns)]

    def _forward(self, sample: PoseSample) -> PoseSample:
        q, qd_measured = sample.joints, sample.joint_velocities
        n = self.model.n_joints
        if q is None or len(q) != n or (qd_measured is not None and len(qd_measured) != n):
            got = (
                "no joint angles"
                if q is None
                else (f"{len(q)} joint angles" if len(q) != n else f"{len(qd_measured)} joint velocities")  # type: ignore[arg-type]  # the branch where they were given, and mismatched
            )
            raise ConfigError(
                f"kinematics.joints: the inner source gives {got}; {self.model.source} needs {n} "
                f"({', '.join(self.model.joint_names)})"
            )
        qd, qdd = self._rates.update(sample.t_ns, q, qd_measured)
        if qd is None:  # the first readings of a source without velocities: the pose only
            R_BE, p_BoEo_B = self.model.pose(q)
            w_BE_E = alpha_BE_E = a_BEo_B = None
        else:
            R_BE, p_BoEo_B, w_BE_E, alpha_BE_E, a_BEo_B = self.model.motion(q, qd, np.zeros(n) if qdd is None else qdd)
            if qdd is None:
                alpha_BE_E = a_BEo_B = None
        return PoseSample(
            t_ns=sample.t_ns,
            quat_BE=self.model.quaternion(R_BE),
            p_BoEo_B=p_BoEo_B,
            joints=q,
            joint_velocities=qd_measured,
            w_BE_E=w_BE_E,
            alpha_BE_E=alpha_BE_E,
            a_BEo_B=a_BEo_B,
        )

    def close(self) -> None:
        """Close the inner source."""
        self.inner.close()

    def drain_events(self) -> list[Event]:
        """The inner source's events since the last call (none if it emits none)."""
        return self._inner_events.drain_events() if self._inner_events is not None else []

    def health_counters(self) -> dict[str, int]:
        """The inner source's link health counters (empty if it keeps none)."""
        return self._inner_health.health_counters() if self._inner_health is not None else {}


def urdf_kinematics(
    urdf: str = "ur5e",
    frame: str = "tool0",
    base: str = "base",
    joints: dict | None = None,
    acceleration_window_s: float = 0.01,
) -> UrdfKinematics:
    """The ``urdf`` source from its config table: the inner source is built from ``joints`` (a table with a ``name``).

    Parameters
    ----------
    urdf : a shipped model (``shipped_models()``: "ur5e") or a path to a URDF file.
    frame : the URDF frame reported as E (the flange "tool0", or a sensor frame the URDF adds).
    base : the URDF frame reported as B ("base": the UR controller's Base frame).
    joints : the inner kinematics source's table: ``name`` and its options, e.g.
        ``{ name = "ur_rtde", address = "192.168.1.10" }``; it must report ``joints``.
    acceleration_window_s : the joint-acceleration fit's window, s.

    The inner source is looked up among the installed plugins (a Registry of its
    own: the built-ins and the entry points, as the command line sees them).
    """
    if joints is None or not isinstance(joints.get("name"), str):
        raise OptionError(
            "joints.name",
            'must name the source of the joint angles, e.g. joints = { name = "ur_rtde", address = "192.168.1.10" }, '
            "got none",
        )
    options: dict[str, Any] = {k: v for k, v in joints.items() if k != "name"}
    model = UrdfModel(urdf, frame, base)  # Pinocchio, the file and its frames: checked before anything connects
    _check_window(acceleration_window_s)
    try:
        inner = Registry().create("kinematics", joints["name"], options, where="kinematics.joints")
    except ConfigError as exc:  # a plugin that names its own keys as if its table were [kinematics]
        message = str(exc)
        if message.startswith("kinematics.") and not message.startswith("kinematics.joints."):
            raise ConfigError("kinematics.joints." + message[len("kinematics.") :]) from None
        raise
    if not isinstance(inner, KinematicsSource):
        raise OptionError("joints.name", f"must be a kinematics source, got {joints['name']!r}")
    return UrdfKinematics(inner, model, acceleration_window_s)


def _check_window(acceleration_window_s: float) -> None:
    number("acceleration_window_s", acceleration_window_s, above=0, maximum=1.0, hint=" s")


@hookimpl
def register_kinematics(register):
    """Register the URDF forward kinematics (Pinocchio) as ``urdf``."""
    register("urdf", urdf_kinematics)
