"""A stated tool mass: a session that started with the tool resting on tissue holds the force until it is free."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.sessions.bench.faults import FAULTS, measure, session
from hapticlab.sessions.live.stated_weight import STILL_NS, StatedWeight

DOWN = np.array([0.0, 0.0, -1.0])  # gravity's direction in B


def test_a_weight_off_the_stated_one_is_a_reason_within_the_tolerance_none():
    stated = StatedWeight(0.35)  # 3.43 N
    assert stated.check((3.43 - 0.25) * DOWN) == ""
    reason = stated.check((3.43 - 2.0) * DOWN)
    assert reason.startswith("tool weight off its stated mass (identified 1.43 N, the stated 0.35 kg weighs 3.43 N")
    assert stated.missing_N == pytest.approx(2.0, abs=0.01)
    assert StatedWeight(10.0).tolerance_N == pytest.approx(0.05 * 98.0665)  # a heavy tool: 5 %


def test_the_weight_is_gone_once_the_residual_shows_it_for_half_a_second_while_the_estimate_stays_put():
    stated = StatedWeight(0.35)
    g_B = list(1.43 * DOWN)
    stated.check(g_B)
    shown = list(2.0 * DOWN + [0.05, 0.0, 0.0])  # the missing 2 N pulling down, a little noise beside it
    said = [stated.gone(t, shown, g_B) for t in range(0, STILL_NS + 20_000_000, 20_000_000)]
    assert not any(said[:-2]) and said[-1]
    # a residual that is not the missing weight (a contact pushing up), or none at all, is not
    stated.showing = None
    assert not any(stated.gone(t, list(-2.0 * DOWN), g_B) for t in range(0, 2 * STILL_NS, 20_000_000))
    assert not stated.gone(0, None, g_B)


def test_an_estimate_still_moving_is_left_to_converge():
    """rls's weight moves by newtons in its first second: its residual shows its own error as the missing
    weight would, and it fixes it itself."""
    stated = StatedWeight(0.35)
    t = 0
    for weight in np.linspace(5.6, 3.9, 40):  # converging from above, 20 ms apart
        g_B = list(weight * DOWN)
        stated.check(g_B)
        assert not stated.gone(t, list((3.43 - weight) * DOWN), g_B)
        t += 20_000_000


@pytest.mark.parametrize("estimator", ["rls", "kalman"])
def test_a_tool_lifted_slowly_off_the_tissue_it_started_on_is_not_pushed_at_the_hand_once_its_mass_is_stated(estimator):
    """Lifted over 0.1 s nothing steps; stated, the force is held from the start (the identified weight is off
    the stated one) and the weight re-identified once free (without it: ``test_pull.py``)."""
    fault = FAULTS["the same, the tool's mass stated (0.35 kg)"]
    r = measure(estimator, session(estimator, {"settings": fault["settings"]}), fault)
    print(f"\n{estimator}: {r}")
    assert r["made_up_force_N"] <= 0.5 and r["over_half_newton_s"] == 0.0
    assert r["event"].startswith("weight_step: weight step of 2.0")
