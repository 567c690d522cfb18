"""The skill metrics (``sessions/review/skill.py``) against profiles computed by hand or in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from hapticlab.sessions.review import skill


def test_peak_and_force_time_integral_by_hand():
    force = np.array([0.0, 1.0, 2.0, 3.0, 2.0])
    assert skill.peak_force(force) == 3.0
    assert skill.force_time_integral(force, 0.01) == pytest.approx(0.08)  # (0+1+2+3+2) N x 10 ms
    assert math.isnan(skill.peak_force(np.array([])))


def test_force_rate_of_a_ramp_and_of_a_sine():
    t = np.arange(0, 2.0, 0.001)
    mean, peak = skill.force_rate(5.0 * t, 0.001)  # 5 N/s: a running mean does not change a ramp's slope
    assert mean == pytest.approx(5.0, rel=1e-9) and peak == pytest.approx(5.0, rel=1e-9)
    # A sin(2 pi f t) over whole periods: mean |dF/dt| = 4 A f, max = 2 pi A f; the 50 ms running mean scales the
    # sine by sin(pi f w) / (pi f w) (0.9990 at f = 0.5 Hz)
    A, f = 2.0, 0.5
    t = np.arange(8049) * 0.001  # the 50-sample running mean keeps 8000 samples: four whole periods
    mean, peak = skill.force_rate(A * np.sin(2 * np.pi * f * t), 0.001)
    gain = math.sin(math.pi * f * 0.05) / (math.pi * f * 0.05)
    assert mean == pytest.approx(4 * A * f * gain, rel=3e-3)
    assert peak == pytest.approx(2 * math.pi * A * f * gain, rel=1e-3)


def _gaussian_sparc() -> float:
    """SPARC of a Gaussian in closed form: its spectrum is a Gaussian, M(u) = exp(-ln(20) u^2) on the band up to
    where it falls to 0.05 (u = f / f*), whatever the Gaussian's width or height: the arc length of M on [0, 1]."""
    a = math.log(20.0)
    value, _ = quad(lambda u: math.sqrt(1.0 + (2 * a * u * math.exp(-a * u * u)) ** 2), 0.0, 1.0)
    return -value


@pytest.mark.parametrize(("sigma", "height"), [(0.2, 1.0), (0.4, 7.5)])
def test_sparc_of_a_gaussian_profile_matches_its_closed_form(sigma, height):
    rate = 100.0
    t = np.arange(-2.0, 2.0, 1.0 / rate)
    g = height * np.exp(-0.5 * (t / sigma) ** 2)
    assert skill.sparc(g, rate) == pytest.approx(_gaussian_sparc(), rel=0.01)  # -1.43: a single smooth bump


def test_sparc_reads_a_press_with_a_tremor_as_less_smooth():
    rate = 100.0
    t = np.arange(0, 4.0, 1.0 / rate)
    press = np.sin(np.pi * t / 4.0) ** 2
    shaky = press * (1 + 0.3 * np.sin(2 * np.pi * 3.0 * t))  # a 3 Hz wobble in the force
    two = np.sin(np.pi * t / 2.0) ** 2  # two presses in the same time
    assert skill.sparc(shaky, rate) < skill.sparc(press, rate) - 0.5
    assert skill.sparc(two, rate) < skill.sparc(press, rate)
    assert math.isnan(skill.sparc(np.zeros(50), rate))


def test_excess_force_events_merge_close_runs_and_time_each():
    t = np.arange(0, 3.0, 0.01)
    force = np.full_like(t, 1.0)
    force[(t >= 0.50) & (t < 0.70)] = 4.0  # one run, 0.2 s
    force[(t >= 0.75) & (t < 0.80)] = 5.0  # 0.05 s later: the same excursion
    force[(t >= 2.00) & (t < 2.10)] = 3.5  # far after: a second event
    events = skill.excess_force_events(t, force, 3.0, merge_gap_s=0.1)
    assert len(events) == 2
    (s1, d1, p1), (s2, d2, p2) = events
    assert s1 == pytest.approx(0.50) and d1 == pytest.approx(0.30) and p1 == 5.0
    assert s2 == pytest.approx(2.00) and d2 == pytest.approx(0.10) and p2 == 3.5
    assert skill.excess_force_events(t, np.ones_like(t), 3.0, 0.1) == []


def test_path_length_of_a_square():
    p = np.array([[0, 0, 0], [0.01, 0, 0], [0.01, 0.01, 0], [0, 0.01, 0], [0, 0, 0]], dtype=float)
    assert skill.path_length(p) == pytest.approx(0.04)
    assert skill.path_length(p[:1]) == 0.0
