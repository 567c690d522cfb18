"""Training tasks: the ``[task]`` table, what it sets up in a simulated world, the simulated hand's scripts,
and the scores against outcomes worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.errors import ConfigError
from hapticlab.plugins.haptics.sim_hand import MARK_S, Palpate, Trace
from hapticlab.plugins.simworld.tissue import Tissue
from hapticlab.sessions.config import apply_overrides, load_config
from hapticlab.sessions.tasks import prepare
from hapticlab.sessions.tasks.scoring import score


def teleop_sim(*overrides: str) -> dict:
    config, _ = load_config("teleop-sim")
    return apply_overrides(config, list(overrides))


def test_no_task_leaves_the_config_as_it_is():
    config = teleop_sim()
    assert prepare(config) is config


def test_palpation_places_an_inclusion_drawn_from_the_seed_within_the_span():
    config = prepare(teleop_sim("task.name=palpation"))
    tissue = config["world"]["contacts"][0]
    offset = np.array(config["task"]["inclusion_offset_B"])
    assert np.allclose(np.array(tissue["inclusion_B"]) - tissue["surface_B"], offset)
    assert abs(offset[0]) <= 0.015 and offset[1] == offset[2] == 0.0  # along the master's x, within span/2
    assert tissue["inclusion_stiffness"] == 3 * tissue["stiffness"]
    again = prepare(teleop_sim("task.name=palpation"))
    other = prepare(teleop_sim("task.name=palpation", "world.seed=12"))
    assert again["task"]["inclusion_offset_B"] == config["task"]["inclusion_offset_B"]
    assert other["task"]["inclusion_offset_B"] != config["task"]["inclusion_offset_B"]
    haptic = config["haptic"]
    assert haptic["script"] == "palpate" and haptic["span"] == pytest.approx(0.03 / 0.5)  # the span at the master
    assert config["session"]["task"] == "palpation"
    assert config["session"]["duration"] >= haptic["press_at"] + 6 * (0.5 + 2 * 0.6 + 1.0)  # the hand's script fits


def test_a_stated_inclusion_is_kept():
    config = prepare(teleop_sim("task.name=palpation", "task.inclusion_offset_B=[0.004, 0.0, 0.0]"))
    assert config["task"]["inclusion_offset_B"] == [0.004, 0.0, 0.0]


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ('task.name="suturing"', "task.name: must be '', 'palpation', 'retraction' or 'tracing', got 'suturing'"),
        ("task.band=[3.0, 1.0]", "task.band: must be [low, high] with low < high"),
        ("task.force_limit=-1", "task.force_limit: must be"),
        ("task.depth=1", "task.depth: unknown option"),
        ("task.CHECKS=1", "task.CHECKS: unknown option"),
        ("teleop.enabled=false", "task.name: palpation is done through teleoperation"),
    ],
)
def test_a_bad_task_is_one_line_naming_the_key(override, message):
    with pytest.raises(ConfigError) as exc:
        prepare(teleop_sim("task.name=palpation", override))
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_the_inclusion_is_stiffer_only_within_its_radius():
    tissue = Tissue(
        surface_B=(0.0, 0.0, 0.0), stiffness=1000.0, damping=0.0, inclusion_B=(0.01, 0.0, 0.0), inclusion_radius=0.005
    )
    x = np.array([[0.012, 0.0, -0.002], [0.020, 0.0, -0.002]])  # 2 mm deep: over the inclusion, and beside it
    f = tissue.force_B_at(x, np.zeros((2, 3)))
    assert f[0, 2] == pytest.approx(12000.0 * 0.002) and f[1, 2] == pytest.approx(1000.0 * 0.002)


def test_the_palpating_hand_marks_the_firmest_probe():
    hand = Palpate(press_at=0.0, depth=0.01, ramp=0.2, hold=0.4, span=0.04, probes=5, mark_button=1)
    firm = 3  # the probe over the inclusion: pushes back harder
    t, marks, where = 0.0, [], []
    while t < 12.0:
        p, _, buttons = hand.intent(t, np.zeros(3))
        probe = int(np.argmin(np.abs(hand.x - p[0])))
        force = np.array([0.0, 0.0, (3.0 if probe == firm else 1.5) * (p[2] < -0.009)])
        hand.intent(t, force)  # what the hand feels at t
        if buttons:
            marks.append(t)
            where.append(p.copy())
        t += 0.001
    assert buttons == 0 and marks  # pressed, then released
    assert marks[-1] - marks[0] == pytest.approx(MARK_S, abs=0.002)
    assert all(abs(w[0] - hand.x[firm]) < 1e-9 and w[2] == pytest.approx(-0.01) for w in where)  # down, on it


def test_the_tracing_hand_slides_along_the_line_while_pressed():
    hand = Trace(press_at=1.0, depth=0.01, ramp=0.5, hold=2.0, span=0.06)
    down = [hand.intent(t, np.zeros(3))[0] for t in np.arange(2.0, 4.0, 0.01)]
    assert all(p[2] == pytest.approx(-0.01) for p in down)
    assert down[0][0] == pytest.approx(-0.03, abs=1e-4) and down[-1][0] == pytest.approx(0.03, abs=1e-4)


def _gathered(**changes):
    base = {
        "marks": [],
        "first_p": np.zeros(3),
        "peak_force_N": 2.0,
        "in_band_s": 0.0,
        "targets": (np.zeros(0), np.zeros((0, 3))),
        "contacts": [],
        "excess_force_events": 0,
    }
    return {**base, **changes}


PALPATION = {"name": "palpation", "force_limit": 3.0, "inclusion_offset_B": [0.01, 0.0, 0.0], "inclusion_radius": 0.006}


@pytest.mark.parametrize(
    ("mark_x", "peak", "expected"),
    [
        (0.013, 2.0, 100.0),  # 3 mm off: within the radius
        (0.019, 2.0, 50.0),  # 9 mm: halfway between one radius and two
        (0.023, 2.0, 0.0),  # 13 mm: beyond two radii
        (0.010, 6.0, 50.0),  # on it, but twice the force limit
    ],
)
def test_palpation_scores_the_distance_and_the_force(mark_x, peak, expected):
    mark = [(5.0, np.array([mark_x, 0.0, -0.004]))]  # the depth (along the normal) does not count
    points, outcome = score(PALPATION, _gathered(marks=mark, peak_force_N=peak))
    assert points == pytest.approx(expected) and outcome["mark_error_m"] == pytest.approx(abs(mark_x - 0.01))
    assert score(PALPATION, _gathered())[0] == 0.0  # no mark


def test_retraction_scores_the_share_of_the_hold_in_band():
    task = {"name": "retraction", "hold": 2.0, "band": [1.5, 2.5]}
    assert score(task, _gathered(in_band_s=1.0))[0] == 50.0
    assert score(task, _gathered(in_band_s=3.0))[0] == 100.0


def test_tracing_scores_the_distance_from_the_line_its_coverage_and_the_events():
    task = {"name": "tracing", "span": 0.03, "tolerance": 0.003}
    xs = np.linspace(-0.015, 0.015, 31)
    targets = (np.arange(len(xs)) * 0.1, np.c_[xs, np.full_like(xs, 0.0015), np.full_like(xs, 0.002)])  # 1.5 mm beside
    gathered = _gathered(targets=targets, contacts=[(0.0, 3.0)])
    points, outcome = score(task, gathered)
    assert outcome["path_error_m"] == pytest.approx(0.0015) and outcome["coverage"] == pytest.approx(1.0)
    assert points == pytest.approx(50.0)
    assert score(task, {**gathered, "excess_force_events": 1})[0] == pytest.approx(40.0)
    half = _gathered(targets=targets, contacts=[(0.0, 1.5)])  # in contact over the first half only
    assert score(task, half)[1]["coverage"] == pytest.approx(0.5)
