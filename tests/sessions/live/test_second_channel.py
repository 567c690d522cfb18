"""The robot's own wrench as a second channel: the cross-check against the wrist sensor, and what it confirms.

The robot's side is the simulated UR5e's (``simworld.robot_wrench``: the world's contact with a seeded offset
and noise); the sensor's side is the world's contact in S with the sensor's noise, as a converged estimator
sees it, or the whole session loop.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from hapticlab.core.types import PoseSample
from hapticlab.plugins.simworld.contacts import Indentation
from hapticlab.plugins.simworld.physics import SimWorld
from hapticlab.plugins.simworld.robot_wrench import RobotWrench
from hapticlab.sessions.bench.faults import FAULTS, measure, session
from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session, run_session
from hapticlab.sessions.live.crosscheck import AGREE_NS, WrenchCrossCheck
from hapticlab.sessions.recording import read_recording

RATE_HZ, ROBOT_EVERY = 1000, 2  # the sensor at 1 kHz, the robot at 500 Hz


def channels(world: SimWorld, seconds: float, sensor_offset_S=None, seed: int = 3):
    """Feed a cross-check tick by tick (1 ms) from ``world``: the robot's wrench, and the estimator's contact
    (the world's contact in S, sensor noise 0.12 N per axis, plus ``sensor_offset_S(t)``); what it said per tick."""
    check = WrenchCrossCheck(RobotWrench(world).accuracy)
    robot = RobotWrench(world)
    t_ns = np.arange(1, round(seconds * RATE_HZ)) * (1_000_000_000 // RATE_HZ)
    t = t_ns * 1e-9
    truth = world.wrench(t, noise=False)
    R_SE = world.R_SE
    contact_S = truth["contact_force_S"] + np.random.default_rng(seed).normal(0, 0.12, (len(t), 3))
    if sensor_offset_S is not None:
        contact_S += sensor_offset_S(t)
    wrench_B = robot.measured(t, t_ns)
    holding, confirmed = [], []
    for i in range(len(t)):
        if i % ROBOT_EVERY == 0:
            pose = PoseSample(t_ns=int(t_ns[i]), quat_BE=np.array([1.0, 0, 0, 0]), wrench_B=wrench_B[i])
            check.add_robot([pose])
        check.add_contact(t_ns[i : i + 1], contact_S[i : i + 1], truth["R_EB"][i : i + 1], R_SE)
        holding.append(check.holding)
        confirmed.append(check.confirmed)
    return check, t, holding, confirmed


def test_the_two_channels_agree_through_a_session_of_contacts():
    world = SimWorld(contacts=[Indentation(1.0, 1.5, 6.0, 0.3), Indentation(4.0, 1.0, 15.0, 0.2)], seed=11)
    check, _, holding, _ = channels(world, 6.0)
    assert check.compared > 0 and check.disagreements == 0 and not any(holding)


def test_a_sensor_offset_beyond_the_robot_s_accuracy_holds_the_force_until_they_agree_again():
    world = SimWorld(seed=12)
    offset = lambda t: np.where((t >= 1.0) & (t < 2.0), 7.0, 0.0)[:, None] * np.array([0.0, 0.0, 1.0])  # noqa: E731
    _, t, holding, _ = channels(world, 3.0, offset)
    held = np.array([bool(h) for h in holding])
    first, last = t[held][0], t[held][-1]
    assert 1.0 <= first <= 1.0 + 0.045  # within the bin and the one after it
    assert "wrist sensor and robot disagree (the contact force is" in holding[int(np.flatnonzero(held)[0])]
    # ...until they have agreed for AGREE_NS, counted from the first bin after the offset
    assert 2.0 + AGREE_NS * 1e-9 <= last <= 2.0 + AGREE_NS * 1e-9 + 0.045
    assert not held[t > last].any()


def test_an_offset_within_the_robot_s_accuracy_is_not_its_to_see():
    """The second channel is coarse: 2 N on the sensor is within what the robot's own error could be."""
    world = SimWorld(seed=12)
    check, *_ = channels(world, 2.0, lambda t: np.tile([0.0, 2.0, 0.0], (len(t), 1)))
    assert check.disagreements == 0


@pytest.mark.parametrize(
    ("sensor_step", "robot_sees", "confirmed"),
    [
        (10.0, True, True),  # a collision: both channels step alike, the robot's force well beyond its accuracy
        (10.0, False, False),  # the sensor's alone: a fault
        (2.0, True, False),  # a real 2 N step, but within what the robot's zero could be (its offset: 1.5 N)
    ],
)
def test_a_sudden_step_is_confirmed_only_when_the_robot_shows_it_beyond_its_accuracy(
    sensor_step, robot_sees, confirmed
):
    start_ns = 1_000_000_000
    world = SimWorld(contacts=[Indentation(start_ns * 1e-9, 0.5, sensor_step, 0.0)] if robot_sees else [], seed=13)
    check, robot = WrenchCrossCheck(4.0), RobotWrench(world)
    t_ns = np.arange(1, 1500) * 1_000_000
    t = t_ns * 1e-9
    truth = world.wrench(t, noise=False)
    contact_S = truth["contact_force_S"].copy()
    if not robot_sees:  # the sensor's alone: a fault, along the sensor's z
        contact_S[t_ns >= start_ns, 2] += sensor_step
    wrench_B = robot.measured(t, t_ns)
    said = ""
    for i in range(len(t)):
        if i % ROBOT_EVERY == 0:
            check.add_robot([PoseSample(t_ns=int(t_ns[i]), quat_BE=np.array([1.0, 0, 0, 0]), wrench_B=wrench_B[i])])
        if t_ns[i] == start_ns:  # the gate marks the step at the sample that made it
            check.mark(int(t_ns[i]))
        check.add_contact(t_ns[i : i + 1], contact_S[i : i + 1], truth["R_EB"][i : i + 1], world.R_SE)
        said = said or check.confirmed
    assert bool(said) == confirmed, said


def demo(estimator: str, wrench_accuracy: float, contacts=(), duration_s: float = 6.5):
    config, _ = load_config("demo")
    config = apply_settings(
        config,
        {
            "session.realtime": False,
            "session.duration": duration_s,
            "estimator.name": estimator,
            "kinematics.wrench_accuracy": wrench_accuracy,
        },
    )
    config["world"]["contacts"] = [*config["world"]["contacts"], *contacts]
    with tempfile.TemporaryDirectory() as folder:
        result = run_session(build_session(config), out=Path(folder) / "x.mcap")
        rec = read_recording(result.path)
    t0 = result.events[0].t_ns
    commands = rec.topics["/haptic/command"][:-1]
    t = (np.array([t for t, _ in commands]) - t0) * 1e-9
    return t, np.array([m["force_D"] for _, m in commands]), result.events, rec


def test_a_collision_in_one_millisecond_is_felt_once_the_robot_shows_it_too():
    """10 N in 1 ms is faster than any contact the sensor's rules let through: held out as a glitch for 0.2 s, then
    held as a sudden step until the motion tells. The robot's own wrench shows it too: felt after the glitch hold."""
    collision = {"kind": "indentation", "start": 5.0, "duration": 0.6, "peak_force": 10.0, "ramp": 0.0}
    felt = {}
    for accuracy in (4.0, 0.0):
        t, force, events, _ = demo("rls", accuracy, [collision])
        inside = (t >= 5.0) & (t < 5.6)
        on = inside & (np.linalg.norm(force, axis=1) > 0)
        felt[accuracy] = t[on][0] - 5.0 if on.any() else None
        if accuracy:
            assert any(e.kind == "contact_confirmed" and "the robot's own force stepped" in e.message for e in events)
    print(f"\nfirst force after the collision: {felt}")
    assert felt[4.0] is not None and felt[4.0] <= 0.25
    assert felt[0.0] is None


def test_the_robot_s_wrench_is_recorded_with_each_pose():
    _, _, _, rec = demo("rls", 4.0, duration_s=1.0)
    poses = rec.topics["/kinematics/pose"]
    assert poses and all(len(m["wrench_B"]) == 6 for _, m in poses)
    _, _, _, rec = demo("rls", 0.0, duration_s=1.0)
    assert all(m["wrench_B"] is None for _, m in rec.topics["/kinematics/pose"])


RAMP_IN_CONTACT = "sensor offset ramping +6 N over 0.5 s, during a contact"


def ramp_in_contact() -> dict:
    """The bench's +6 N ramp in a contact against the same session without it (kalman): ``measure``'s numbers."""
    fault = dict(FAULTS[RAMP_IN_CONTACT])
    duration_s = fault.pop("session_s")
    r = measure("kalman", session("kalman", None, duration_s), {**fault, "session_s": duration_s})
    print(f"\n{RAMP_IN_CONTACT}: {r}")
    return r


def test_a_bias_ramping_fast_in_a_contact_is_cut_short_by_the_second_channel(monkeypatch):
    """6 N over 0.5 s in a contact: too slow for a step, and the drift watch cannot judge in a contact. With the
    lever watch out of the way (as on an estimator whose torque stage has not converged), the robot's wrench
    disagrees once the offset passes its accuracy; without it the force is wrong until the contact ends and the
    drift watch sees the bias."""
    from hapticlab.sessions.live.lever import LeverWatch

    monkeypatch.setattr(LeverWatch, "_close", lambda self: None)
    with_robot = ramp_in_contact()
    assert with_robot["event"].startswith("fault: wrist sensor and robot disagree")
    assert with_robot["detected_after_s"] <= 0.6


def test_a_bias_ramping_fast_in_a_contact_twists_the_residual_before_the_robot_disagrees():
    """The same fault with the defaults: the contact's torque is its tip's lever times its force, the bias
    adds force with no torque, so the residual twists about its own line within about half a newton of bias
    (measured: 0.58 N made up, caught after 60 ms), long before the robot's 4 N accuracy (4.0 N made up)."""
    r = ramp_in_contact()
    assert r["event"].startswith("fault: residual not a contact's: it twists about its own line")
    assert r["detected_after_s"] <= 0.1 and r["made_up_force_N"] <= 0.65


def test_the_channels_agree_with_the_sensor_mounted_turned_on_the_flange():
    """The contact turned from S into B through the mount (R_SE) and the poses: a transpose anywhere and a
    contact of 15 N would disagree with the robot's by far more than 4 N."""
    from hapticlab.plugins.simworld.params import SensorParams

    world = SimWorld(
        sensor=SensorParams(mount_rotation_SE=np.array([0.3, -0.5, 1.2])),
        contacts=[Indentation(1.0, 1.5, 15.0, 0.3, direction_B=np.array([0.6, 0.0, 0.8]))],
        seed=14,
    )
    check, *_ = channels(world, 3.0)
    assert check.compared > 100 and check.disagreements == 0


def feed(check, bins: list[tuple[list[float] | None, list[float] | None]], first: int = 0) -> list[str]:
    """One robot and one sensor force (3,) N per 20 ms bin from bin ``first`` (None: none that bin); what the check
    said after each."""
    said = []
    for k, (robot, sensor) in enumerate(bins, start=first):
        for t in range(k * 20_000_000, (k + 1) * 20_000_000, 2_000_000):
            if robot is not None:
                check.add_robot([PoseSample(t_ns=t, quat_BE=np.array([1.0, 0, 0, 0]), wrench_B=np.r_[robot, 0, 0, 0])])
            if sensor is not None:
                check.add_contact(np.array([t]), np.array([sensor]), np.eye(3)[None], None)
        said.append(check.holding)
    return said


def test_one_disagreeing_bin_is_a_lagging_robot_two_hold_the_force():
    free, off = [0.0, 0.0, 0.0], [0.0, 0.0, 6.0]
    assert not any(feed(WrenchCrossCheck(4.0), [(free, free)] * 3 + [(free, off)] + [(free, free)] * 3))
    said = feed(WrenchCrossCheck(4.0), [(free, free)] * 3 + [(free, off)] * 2 + [(free, free)] * 3)
    assert any(said) and said[-1].startswith("wrist sensor and robot disagree")


def test_bins_never_compared_are_no_agreement_and_a_silent_robot_holds_the_force():
    free, off = [0.0, 0.0, 0.0], [0.0, 0.0, 6.0]
    check = WrenchCrossCheck(4.0)
    # disagree, agree one bin, the sensor's samples withheld for 0.14 s (none reach the check), agree three bins:
    # the hold must wait for AGREE_NS of compared agreement, not for the clock
    bins = [(free, free)] * 2 + [(free, off)] * 3 + [(free, free)] + [(free, None)] * 7 + [(free, free)] * 3
    said = feed(check, bins)
    assert said[-1].startswith("wrist sensor and robot disagree")
    said = feed(check, [(free, free)] * 12, first=16)
    assert said[-1] == ""
    # the robot's wrench stops (NaN) while the sensor's comes: held, said so; a sudden step then marks safely
    nan = [float("nan")] * 3
    said = feed(check, [(nan, free)] * 12, first=28)
    assert said[-1].startswith("robot's own wrench missing")
    check.mark(40 * 20_000_000)
    assert check.reference is None
