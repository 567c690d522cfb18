"""The ``urdf`` kinematics: the shipped UR5e URDF on Pinocchio against UR's DH table, its motion, the wrapper."""

from __future__ import annotations

import importlib
import sys
import time
from contextlib import contextmanager
from importlib import resources

import numpy as np
import pluggy
import pytest

from hapticlab.core import hookimpl
from hapticlab.core.frames import matrix_from_quat_wxyz, matrix_from_rotvec, quat_wxyz_from_matrix
from hapticlab.core.host import hookspecs
from hapticlab.core.host.interfaces import EmitsEvents, KinematicsSource
from hapticlab.core.host.registry import ConfigError, Registry
from hapticlab.core.types import Event, PoseSample
from hapticlab.plugins.kinematics import urdf as urdf_plugin
from hapticlab.plugins.kinematics.dh_urdf import UR_DYNAMICS, urdf_from_dh
from hapticlab.plugins.kinematics.ur_arm import UR_DH, forward, link_transform
from hapticlab.plugins.kinematics.urdf import JointRates, UrdfKinematics, UrdfModel, shipped_models

DH = UR_DH["ur5e"]
T0 = 1_000_000_000


class JointTrajectory:
    """A smooth joint motion: q(t) = q0 + A sin(2π f t + φ) per joint, rad, with its exact derivatives."""

    def __init__(self, seed: int):
        rng = np.random.default_rng(seed)
        self.q0 = np.array([0.3, -1.4, 1.5, -1.6, -1.5, 0.2]) + rng.uniform(-0.2, 0.2, 6)
        self.amplitude = rng.uniform(0.2, 0.6, 6)  # rad
        self.omega = 2 * np.pi * rng.uniform(0.2, 0.5, 6)  # rad/s (0.2–0.5 Hz, a hand-guided pace)
        self.phase = rng.uniform(0, 2 * np.pi, 6)

    def q(self, t: float) -> np.ndarray:
        return self.q0 + self.amplitude * np.sin(self.omega * t + self.phase)

    def qd(self, t: float) -> np.ndarray:
        return self.amplitude * self.omega * np.cos(self.omega * t + self.phase)

    def qdd(self, t: float) -> np.ndarray:
        return -self.amplitude * self.omega**2 * np.sin(self.omega * t + self.phase)

    @property
    def peak_jerk(self) -> float:
        """The largest |d³q/dt³| of any joint, rad/s³."""
        return float((self.amplitude * self.omega**3).max())


class TrajectoryJointSource:
    """A test double of a controller's joint stream (KinematicsSource, EmitsEvents).

    Reports, at ``rate_hz`` from ``open``, the joint angles (and velocities, unless
    ``velocities`` is False) of a JointTrajectory, with the flange pose a UR
    controller would report beside them (UR's DH forward kinematics).
    """

    def __init__(self, trajectory: JointTrajectory, rate_hz: float = 500.0, velocities: bool = True):
        self.trajectory, self.rate_hz, self.velocities = trajectory, rate_hz, velocities
        self.opened_at: int | None = None
        self.closed = False
        self._next = 0
        self._events = [Event(T0, "link", "connected")]

    def open(self, t0_ns: int) -> None:
        self.opened_at, self._next = t0_ns, 0

    def read(self, until_ns: int) -> list[PoseSample]:
        out = []
        while (t_ns := self.opened_at + round(self._next * 1e9 / self.rate_hz)) <= until_ns:
            t = (t_ns - self.opened_at) / 1e9
            q = self.trajectory.q(t)
            R_BE, p_BoEo_B = forward(DH, q)
            out.append(
                PoseSample(
                    t_ns, quat_wxyz_from_matrix(R_BE), p_BoEo_B, q, self.trajectory.qd(t) if self.velocities else None
                )
            )
            self._next += 1
        return out

    def close(self) -> None:
        self.closed = True

    def drain_events(self) -> list[Event]:
        events, self._events = self._events, []
        return events


def test_the_shipped_ur5e_is_the_generators_output():
    """Reproducible: plugins/kinematics/urdf/ur5e.urdf is urdf_from_dh("ur5e"), byte for byte."""
    shipped = (resources.files("hapticlab.plugins.kinematics") / "urdf" / "ur5e.urdf").read_text()
    assert shipped == urdf_from_dh("ur5e")
    assert shipped_models() == ["ur5e"]


def test_pinocchio_fk_of_the_shipped_urdf_equals_urs_dh_fk():
    """tool0 in base over 2000 random q within the joints' ±2π: the same pose as ur_arm.forward to 1e-9."""
    model = UrdfModel("ur5e", frame="tool0", base="base")
    assert model.n_joints == 6
    assert model.joint_names == [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ]
    rng = np.random.default_rng(13)
    worst = 0.0
    for q in rng.uniform(-2 * np.pi, 2 * np.pi, (2000, 6)):
        R_BE, p_BoEo_B = model.pose(q)
        R_dh, p_dh = forward(DH, q)
        worst = max(worst, np.abs(R_BE - R_dh).max(), np.abs(p_BoEo_B - p_dh).max())
    assert worst < 1e-9, worst
    # base_link is ROS's root: Base turned π about z
    R_LE, p_LoEo_L = UrdfModel("ur5e", base="base_link").pose(q)
    R_z_pi = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(R_LE, R_z_pi @ R_dh, atol=1e-12)
    np.testing.assert_allclose(p_LoEo_L, R_z_pi @ p_dh, atol=1e-12)


def test_the_urdf_masses_sit_at_urs_published_centres_of_mass():
    """Each link's mass is UR's, and its centre of mass (in base, Pinocchio) is UR's c_i in DH frame i."""
    pin = pytest.importorskip("pinocchio")
    model = UrdfModel("ur5e")
    dynamics = UR_DYNAMICS["ur5e"]
    q = np.random.default_rng(5).uniform(-np.pi, np.pi, 6)
    pin.forwardKinematics(model.model, model.data, q)
    T = np.eye(4)
    for i in range(6):
        T = T @ link_transform(DH, i, q[i])  # DH frame i+1 in Base
        inertia = model.model.inertias[i + 1]
        assert inertia.mass == dynamics.mass[i]
        com_W = model.data.oMi[i + 1].act(inertia.lever)
        np.testing.assert_allclose(
            model.R_BW @ (com_W - model.p_WoBo_W), T[:3, :3] @ dynamics.com[i] + T[:3, 3], atol=1e-12
        )


def _finite_difference_motion(model: UrdfModel, trajectory: JointTrajectory, t: float, h: float):
    """(w_BE_E, alpha_BE_E, a_BEo_B) of the FK along the trajectory by central differences of step h (s)."""

    def w_E(tt):  # ω_E = vee(R_BEᵀ Ṙ_BE)
        R_minus, R, R_plus = (model.pose(trajectory.q(tt + k * h))[0] for k in (-1, 0, 1))
        W = R.T @ (R_plus - R_minus) / (2 * h)
        return np.array([W[2, 1] - W[1, 2], W[0, 2] - W[2, 0], W[1, 0] - W[0, 1]]) / 2

    p = [model.pose(trajectory.q(t + k * h))[1] for k in (-1, 0, 1)]
    return w_E(t), (w_E(t + h) - w_E(t - h)) / (2 * h), (p[2] - 2 * p[1] + p[0]) / h**2


def test_velocity_and_accelerations_match_finite_differences_of_the_fk():
    """UrdfModel.motion with the exact q, q̇, q̈ of a smooth trajectory: ω, α, a equal central differences of FK."""
    model = UrdfModel("ur5e")
    trajectory = JointTrajectory(seed=21)
    worst = np.zeros(3)
    for t in np.linspace(0.0, 4.0, 41):
        _, _, w, alpha, a = model.motion(trajectory.q(t), trajectory.qd(t), trajectory.qdd(t))
        w_fd, alpha_fd, a_fd = _finite_difference_motion(model, trajectory, t, h=1e-4)
        worst = np.maximum(worst, [np.abs(w - w_fd).max(), np.abs(alpha - alpha_fd).max(), np.abs(a - a_fd).max()])
    # the central differences' own truncation error (h = 1e-4 s) is ~1e-7: measured 9e-8, 5e-7, 1e-7
    assert worst[0] < 1e-6 and worst[1] < 1e-5 and worst[2] < 1e-5, worst  # rad/s, rad/s², m/s²


def test_joint_rates_fit_the_acceleration_causally():
    """Measured q̇: q̈ from a line through the newest q̇; q only: q̇ and q̈ from a quadratic; None until enough."""
    trajectory = JointTrajectory(seed=3)
    with_velocities, from_angles = JointRates(0.01), JointRates(0.01)
    errors = {"qdd": [], "qd_fit": [], "qdd_fit": []}
    for k in range(1000):
        t = k / 500.0
        qd, qdd = with_velocities.update(T0 + k * 2_000_000, trajectory.q(t), trajectory.qd(t))
        qd_fit, qdd_fit = from_angles.update(T0 + k * 2_000_000, trajectory.q(t), None)
        np.testing.assert_array_equal(qd, trajectory.qd(t))
        if k == 0:
            assert qdd is None and qd_fit is None and qdd_fit is None
            continue
        if k == 1:
            assert qd_fit is None and qdd_fit is None
            continue
        errors["qdd"].append(np.abs(qdd - trajectory.qdd(t)).max())
        errors["qd_fit"].append(np.abs(qd_fit - trajectory.qd(t)).max())
        errors["qdd_fit"].append(np.abs(qdd_fit - trajectory.qdd(t)).max())
    # the fits' bias from the jerk j over the window W (derived for 5 readings 2 ms apart, s = −2 … −10 ms):
    # q̈ from the line through the newest q̇ is off by ½ j Σs³/Σs² = 0.41 j W, from the quadratic in q by
    # 0.48 j W, and q̇ from the quadratic by 0.077 j W² (each bound here 10 % above: the jerk is not constant)
    jerk, window = trajectory.peak_jerk, 0.01
    assert max(errors["qdd"]) < 0.45 * jerk * window, (max(errors["qdd"]), jerk)  # measured 0.037 rad/s², j = 9.2
    assert max(errors["qd_fit"]) < 0.085 * jerk * window**2, (max(errors["qd_fit"]), jerk)
    assert max(errors["qdd_fit"]) < 0.53 * jerk * window, (max(errors["qdd_fit"]), jerk)
    # a reading that is not finite is kept out of later windows
    rates = JointRates(0.01)
    for k in range(5):
        rates.update(T0 + k * 2_000_000, trajectory.q(k / 500), trajectory.qd(k / 500))
    assert rates.update(T0 + 5 * 2_000_000, np.full(6, np.nan), trajectory.qd(0.01))[1] is None
    _, qdd = rates.update(T0 + 6 * 2_000_000, trajectory.q(0.012), trajectory.qd(0.012))
    assert np.isfinite(qdd).all()


@pytest.mark.parametrize("velocities", [True, False], ids=["q and qd", "q only"])
def test_the_plugin_over_a_joint_source_reports_the_fk_and_its_motion(velocities):
    """Wrapping a 500 Hz joint stream: each pose is the FK of its joints, ω/α/a those of the trajectory."""
    trajectory = JointTrajectory(seed=8)
    inner = TrajectoryJointSource(trajectory, velocities=velocities)
    kinematics = UrdfKinematics(inner, UrdfModel("ur5e"))
    assert isinstance(kinematics, KinematicsSource) and isinstance(kinematics, EmitsEvents)
    assert kinematics.rate_hz == 500.0
    kinematics.open(T0)
    assert inner.opened_at == T0
    poses = []
    for until in [*range(T0, T0 + 2_000_000_000, 7_000_000), T0 + 2_000_000_000]:  # every 7 ms, as a loop would
        poses += kinematics.read(until)
    assert [p.t_ns for p in poses] == [T0 + k * 2_000_000 for k in range(1001)]
    assert [e.message for e in kinematics.drain_events()] == ["connected"]
    model, rates = UrdfModel("ur5e"), JointRates(kinematics.acceleration_window_s)
    plumbing = 0.0  # against UrdfModel.motion over JointRates' q̇, q̈: the plugin adds nothing of its own
    worst = np.zeros(5)  # against the trajectory's exact motion: the fit's bias only
    for k, pose in enumerate(poses):
        t = k / 500.0
        q = trajectory.q(t)
        np.testing.assert_array_equal(pose.joints, q)
        R_BE, p_BoEo_B = forward(DH, q)
        worst[:2] = np.maximum(
            worst[:2],
            [np.abs(matrix_from_quat_wxyz(pose.quat_BE) - R_BE).max(), np.abs(pose.p_BoEo_B - p_BoEo_B).max()],
        )
        qd, qdd = rates.update(pose.t_ns, q, trajectory.qd(t) if velocities else None)
        if qdd is None:  # the first reading (two without velocities): no acceleration yet
            assert k < (1 if velocities else 2) and pose.alpha_BE_E is None and pose.a_BEo_B is None
            assert (pose.w_BE_E is None) == (qd is None)
            continue
        fitted = model.motion(q, qd, qdd)[2:]
        exact = model.motion(q, trajectory.qd(t), trajectory.qdd(t))[2:]
        got = (pose.w_BE_E, pose.alpha_BE_E, pose.a_BEo_B)
        plumbing = max(plumbing, *(np.abs(g - f).max() for g, f in zip(got, fitted)))
        worst[2:] = np.maximum(worst[2:], [np.abs(g - e).max() for g, e in zip(got, exact)])
    assert plumbing < 1e-12, plumbing
    assert worst[0] < 1e-12 and worst[1] < 1e-12, worst
    # q̈'s fit is off by at most ½ j W per joint (test_joint_rates_fit_the_acceleration_causally); α and a take
    # it through the Jacobian: |J_ω| ≤ 1 per joint, |J_v| ≤ the arm's reach (≈ 1 m), six joints
    bound = 6 * 0.5 * trajectory.peak_jerk * kinematics.acceleration_window_s
    if velocities:
        assert worst[2] < 1e-12, worst  # ω = J(q) q̇ from the measured q̇: exact
    else:
        assert worst[2] < 6 * 0.08 * trajectory.peak_jerk * kinematics.acceleration_window_s**2, worst
    assert worst[3] < bound and worst[4] < bound, (worst, bound)
    kinematics.close()
    assert inner.closed


def test_the_ur_emulators_tcp_pose_is_the_fk_of_its_joints():
    """The RTDE emulator's actual_TCP_pose (Base, rotation vector) equals the URDF FK of its actual_q to 1e-6."""
    emulator_module = importlib.import_module("hapticlab.plugins.kinematics.ur_emulator")
    from hapticlab.plugins.simworld import RandomTour, SimWorld

    emulator = emulator_module.UREmulator(
        SimWorld(motion=RandomTour(seed=4), seed=4), address="127.0.0.1", model="ur5e"
    )
    model = UrdfModel("ur5e")
    worst = 0.0
    for cycle in range(0, 5000, 5):  # 10 s of the 500 Hz controller, every 5th cycle
        state = emulator.state(cycle)
        R_BE, p_BoEo_B = model.pose(np.array(state["actual_q"]))
        tcp = np.array(state["actual_TCP_pose"])
        worst = max(worst, np.abs(p_BoEo_B - tcp[:3]).max(), np.abs(R_BE - matrix_from_rotvec(tcp[3:])).max())
    assert worst < 1e-6, worst


class Tap:
    """Passes an inner source's readings on, keeping a copy (what the controller itself reported)."""

    def __init__(self, inner: KinematicsSource):
        self.inner, self.rate_hz, self.seen = inner, inner.rate_hz, []

    def open(self, t0_ns: int) -> None:
        self.inner.open(t0_ns)

    def read(self, until_ns: int) -> list[PoseSample]:
        samples = self.inner.read(until_ns)
        self.seen += samples
        return samples

    def close(self) -> None:
        self.inner.close()


@contextmanager
def ur_emulator_process(spawn_process, address: str):
    """The RTDE emulator (``hapticlab emulate ur``) in a child process (ur-rtde's constructor holds the GIL, so the
    emulator cannot share this process), yielded once it listens on ``address``:30004."""
    script = "import sys; from hapticlab.sessions.cli import main; sys.exit(main(['emulate', 'ur', *sys.argv[1:]]))"
    process = spawn_process([sys.executable, "-c", script, "--address", address, "--seed", "11"], "emulate ur")
    try:
        line = process.first_line()
        assert f"{address}:30004" in line, line
        yield
    finally:
        process.finish()


def test_over_rtde_the_fk_of_the_controllers_joints_is_its_tcp_pose(spawn_process):
    """ur-rtde against the emulator: the URDF pose of each package's actual_q is its actual_TCP_pose (1e-6)."""
    from hapticlab.plugins.kinematics.ur_rtde import URRTDEKinematics

    tap = Tap(URRTDEKinematics(address="127.0.0.81", rate_hz=500.0))
    kinematics = UrdfKinematics(tap, UrdfModel("ur5e"))
    poses = []
    with ur_emulator_process(spawn_process, "127.0.0.81"):
        kinematics.open(time.monotonic_ns())
        try:
            deadline = time.monotonic() + 10.0  # against hanging, not a timing assertion
            while len(poses) < 250 and time.monotonic() < deadline:
                time.sleep(0.01)
                poses += kinematics.read(time.monotonic_ns() + 10**9)
        finally:
            kinematics.close()
    assert len(poses) >= 250 and len(tap.seen) == len(poses)
    worst = 0.0
    for pose, reported in zip(poses, tap.seen):
        assert pose.t_ns == reported.t_ns
        np.testing.assert_array_equal(pose.joints, reported.joints)
        worst = max(
            worst,
            np.abs(matrix_from_quat_wxyz(pose.quat_BE) - matrix_from_quat_wxyz(reported.quat_BE)).max(),
            np.abs(pose.p_BoEo_B - reported.p_BoEo_B).max(),
        )
    assert worst < 1e-6, worst
    assert all(p.w_BE_E is not None for p in poses) and all(p.alpha_BE_E is not None for p in poses[1:])


# ------------------------------------------------------------------ config and the registry


@hookimpl
def register_kinematics(register):
    """A joint source for the registry tests: a 250 Hz JointTrajectory stream."""
    register("trajectory_joints", lambda rate_hz=250.0, seed=1: TrajectoryJointSource(JointTrajectory(seed), rate_hz))


@pytest.fixture
def registry(monkeypatch) -> Registry:
    """The built-ins plus this module's ``trajectory_joints``; the urdf factory builds its inner source from it."""
    pm = pluggy.PluginManager("hapticlab")
    pm.add_hookspecs(hookspecs)
    for name in ("hapticlab.plugins.kinematics.urdf", "hapticlab.plugins.kinematics.sim"):
        pm.register(importlib.import_module(name), name=name)
    pm.register(sys.modules[__name__], name="test_urdf")
    monkeypatch.setattr(urdf_plugin, "Registry", lambda: Registry(pm))
    return Registry(pm)


def test_built_from_config_with_the_inner_source_named_in_joints(registry):
    kinematics = registry.create(
        "kinematics",
        "urdf",
        {
            "urdf": "ur5e",
            "frame": "tool0",
            "base": "base",
            "joints": {"name": "trajectory_joints", "rate_hz": 125, "seed": 2},
        },
        where="kinematics",
    )
    assert isinstance(kinematics, UrdfKinematics) and kinematics.rate_hz == 125.0
    kinematics.open(T0)
    pose = kinematics.read(T0)[0]
    R_BE, p_BoEo_B = forward(DH, JointTrajectory(2).q(0.0))
    np.testing.assert_allclose(matrix_from_quat_wxyz(pose.quat_BE), R_BE, atol=1e-12)
    np.testing.assert_allclose(pose.p_BoEo_B, p_BoEo_B, atol=1e-12)


def test_a_urdf_file_path_works_like_a_shipped_name(registry, tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text(urdf_from_dh("ur5e"))
    kinematics = registry.create(
        "kinematics",
        "urdf",
        {"urdf": str(path), "frame": "wrist_3_link", "joints": {"name": "trajectory_joints"}},
        where="kinematics",
    )
    kinematics.open(T0)
    q = JointTrajectory(1).q(0.0)
    T = np.eye(4)
    for i in range(5):
        T = T @ link_transform(DH, i, q[i])
    R_BE = matrix_from_quat_wxyz(kinematics.read(T0)[0].quat_BE)
    c, s = np.cos(q[5]), np.sin(q[5])
    np.testing.assert_allclose(R_BE, T[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), atol=1e-12)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({}, r"^kinematics\.joints\.name: must name the source of the joint angles, .* got none"),
        ({"joints": {"rate_hz": 125}}, r"^kinematics\.joints\.name: must name the source"),
        ({"joints": {"name": "nope"}}, r"^kinematics\.joints\.name: unknown kinematics 'nope'"),
        ({"joints": {"name": "trajectory_joints", "rate": 1}}, r"^kinematics\.joints\.rate: unknown option"),
        (
            {"urdf": "ur99", "joints": {"name": "trajectory_joints"}},
            r"^kinematics\.urdf: must be a shipped model \(ur5e\) or a URDF file, got 'ur99'",
        ),
        (
            {"frame": "flange", "joints": {"name": "trajectory_joints"}},
            r"^kinematics\.frame: must be a frame of shipped ur5e \(base, .*\), got 'flange'$",
        ),
        (
            {"base": "wrist_1_link", "joints": {"name": "trajectory_joints"}},
            r"^kinematics\.base: must be a frame fixed to the URDF's root link, got 'wrist_1_link', "
            r"which moves with joint 'wrist_1_joint'",
        ),
        (
            {"acceleration_window_s": 0, "joints": {"name": "trajectory_joints"}},
            r"^kinematics\.acceleration_window_s: must be a finite number > 0 and <= 1 s, got 0",
        ),
        ({"joints": "ur_rtde"}, r"^kinematics\.joints: must be"),
    ],
)
def test_config_errors_name_the_key(registry, options, message):
    with pytest.raises(ConfigError, match=message) as caught:
        registry.create("kinematics", "urdf", options, where="kinematics")
    assert "\n" not in str(caught.value)


def test_a_file_that_is_not_a_urdf_is_named(registry, tmp_path):
    path = tmp_path / "broken.urdf"
    path.write_text("<robot name='x'><link name='a'/>")
    with pytest.raises(ConfigError, match=rf"^kinematics\.urdf: {path} is not a URDF Pinocchio can read") as caught:
        registry.create(
            "kinematics", "urdf", {"urdf": str(path), "joints": {"name": "trajectory_joints"}}, where="kinematics"
        )
    assert "\n" not in str(caught.value)


def test_a_urdf_with_a_continuous_joint_is_refused(registry, tmp_path):
    """Pinocchio gives a continuous joint two angles (cos, sin): not what a controller's joint stream reports."""
    path = tmp_path / "wheel.urdf"
    path.write_text(
        "<robot name='wheel'><link name='a'/><link name='b'/><joint name='j' type='continuous'>"
        "<parent link='a'/><child link='b'/><axis xyz='0 0 1'/></joint></robot>"
    )
    with pytest.raises(
        ConfigError,
        match=r"^kinematics\.urdf: .*wheel\.urdf has joints with more angles than "
        r"velocities .*only revolute and prismatic joints are supported$",
    ):
        registry.create(
            "kinematics",
            "urdf",
            {"urdf": str(path), "frame": "b", "base": "a", "joints": {"name": "trajectory_joints"}},
            where="kinematics",
        )


def test_the_ur_rtde_source_is_named_in_the_joints_table():
    """The built-in registry: ``joints = { name = "ur_rtde", ... }`` builds the RTDE client (not connected yet)."""
    from hapticlab.plugins.kinematics.ur_rtde import URRTDEKinematics

    kinematics = Registry().create(
        "kinematics",
        "urdf",
        {"urdf": "ur5e", "joints": {"name": "ur_rtde", "address": "127.0.0.82", "rate_hz": 125}},
        where="kinematics",
    )
    assert isinstance(kinematics.inner, URRTDEKinematics) and kinematics.inner.address == "127.0.0.82"
    assert kinematics.rate_hz == 125.0
    with pytest.raises(ConfigError, match=r"^kinematics\.joints\.rate_hz: must be a finite number > 0 and <= 500 Hz"):
        Registry().create(
            "kinematics",
            "urdf",
            {"joints": {"name": "ur_rtde", "address": "127.0.0.82", "rate_hz": 1000}},
            where="kinematics",
        )


def test_a_source_without_joint_angles_is_refused_at_its_first_pose():
    class PosesOnly(TrajectoryJointSource):
        def read(self, until_ns):
            return [PoseSample(p.t_ns, p.quat_BE, p.p_BoEo_B) for p in super().read(until_ns)]

    class FiveJoints(TrajectoryJointSource):
        def read(self, until_ns):
            return [PoseSample(p.t_ns, p.quat_BE, p.p_BoEo_B, p.joints[:5]) for p in super().read(until_ns)]

    for source, got in ((PosesOnly, "no joint angles"), (FiveJoints, "5 joint angles")):
        kinematics = UrdfKinematics(source(JointTrajectory(1)), UrdfModel("ur5e"))
        kinematics.open(T0)
        with pytest.raises(
            ConfigError,
            match=rf"^kinematics\.joints: the inner source gives {got}; shipped ur5e "
            r"needs 6 \(shoulder_pan_joint, ",
        ):
            kinematics.read(T0)


def test_without_pinocchio_one_line_says_how_to_install_it(registry, monkeypatch):
    monkeypatch.setitem(sys.modules, "pinocchio", None)  # `import pinocchio` raises ImportError
    with pytest.raises(ConfigError) as caught:
        registry.create("kinematics", "urdf", {"joints": {"name": "trajectory_joints"}}, where="kinematics")
    assert str(caught.value) == ("kinematics.name: the urdf kinematics needs Pinocchio; pip install 'hapticlab[urdf]'")
