"""Force feedback that stays passive: the port's observer and controller, the simulated master and hand, and the
closed loop hand → master → robot → stiff tissue → force → hand with a delay on the link."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics.sim_master import SimMaster
from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.live.passivity import PassivityController
from hapticlab.sessions.recording import read_recording

DT = 0.001


def drive(master: SimMaster, force, seconds: float, controller: PassivityController | None = None) -> np.ndarray:
    """Run ``master`` 1 kHz for ``seconds`` with ``force(p, v)`` (N, in D) through ``controller``; the energy the
    port put into the hand, J, tick by tick (the force sent times the velocity the tick ended at)."""
    energy, total, sent = [], 0.0, None
    for k in range(round(seconds / DT)):
        state = master.state()
        if sent is not None:
            total += float(sent @ state.v_DHo_D) * DT
        energy.append(total)
        f = np.asarray(force(state.p_DoHo_D, state.v_DHo_D), dtype=float)
        if controller is not None:
            f = controller.apply(f, state.v_DHo_D, DT)
        master.send(HapticCommand(k * 1_000_000, f, True))
        sent = f
    return np.array(energy)


def test_the_hand_holds_the_handle_where_it_means_to_against_a_push():
    """At rest the hand's spring balances the device's force: x = x_intent + F / K_hand (the damping and masses
    gone once still)."""
    master = SimMaster(press_at=0.0, depth=0.02, ramp=0.2, hold=10.0, hand_stiffness=400.0)
    drive(master, lambda p, v: [0.0, 0.0, 2.0], 3.0)
    assert master.p[2] == pytest.approx(-0.02 + 2.0 / 400.0, abs=1e-5)
    assert abs(master.v[2]) < 1e-5


def test_a_port_that_feeds_the_motion_is_made_passive():
    """Negative damping (a force along the velocity, what a delayed stiff contact amounts to) pumps energy into
    the hand as it presses and lets go; with the controller the port's energy stays at zero at most (within
    one tick's rounding)."""
    pump = lambda p, v: 6.0 * v  # noqa: E731  (N·s/m: under the hand's 8, so the motion stays bounded)
    free = drive(SimMaster(press_at=0.1, depth=0.01, ramp=0.1, hold=0.5), pump, 2.0)
    controller = PassivityController(max_damping=100.0)
    held = drive(SimMaster(press_at=0.1, depth=0.01, ramp=0.1, hold=0.5), pump, 2.0, controller)
    assert free.max() > 0.005
    assert held.max() <= 1e-6 and controller.active_ticks > 0


def test_the_controller_adds_no_more_than_its_cap_and_nothing_without_a_velocity():
    controller = PassivityController(max_damping=5.0)
    v = np.array([0.0, 0.0, 0.01])
    out = controller.apply(np.array([0.0, 0.0, 10.0]), v, DT)  # 1e-4 J to take out: α = 1000 wanted
    assert controller.damping == 5.0 and out[2] == pytest.approx(10.0 - 5.0 * 0.01)
    force = np.array([0.0, 0.0, 1.0])
    assert controller.apply(force, None, DT) is force and controller.damping == 0.0


def teleop_sim(delay_s: float, passivity: str, tmp_path, long_session):
    config, _ = load_config("teleop-sim")
    config = apply_settings(config, {"teleop.delay_s": delay_s, "teleop.passivity": passivity})
    result = long_session(build_session(config), out=tmp_path / f"teleop_{delay_s}_{passivity}.mcap")
    rec = read_recording(result.path)
    force = np.array([m["force_D"] for _, m in rec.topics["/haptic/command"][:-1]])
    v = np.array([m["v_DHo_D"] for _, m in rec.topics["/haptic/state"]])
    n = min(len(force), len(v))
    # the independent check: each command's force times the handle's velocity at the end of its tick
    energy = np.cumsum(np.einsum("ij,ij->i", force[: n - 1], v[1:n]) * DT)
    recorded = np.array([m["energy_J"] for _, m in rec.topics["/haptic/passivity"]])
    return energy, recorded, force


@pytest.mark.parametrize("delay_s", [0.1, 0.3])
def test_with_a_delayed_link_and_stiff_tissue_the_port_stays_passive_with_the_controller(
    delay_s, tmp_path, long_session
):
    energy, recorded, _ = teleop_sim(delay_s, "on", tmp_path, long_session)
    print(f"\n{delay_s} s, passivity on: max E {energy.max():.4f} J")
    assert energy.max() <= 0.05
    assert abs(recorded.max() - energy.max()) < 0.005  # the controller's own account agrees with the check


def test_without_the_controller_the_same_contact_puts_energy_into_the_hand(tmp_path, long_session):
    """The preset's contact (3000 N/m behind the robot's 8 Hz servo) is unstable without the controller: the
    handle shakes in a limit cycle, the force swinging between zero and the clamp."""
    energy, _, force = teleop_sim(0.3, "off", tmp_path, long_session)
    print(f"\n0.3 s, passivity off: max E {energy.max():.4f} J")
    assert energy.max() > 0.1
    assert np.ptp(force[8000:10000, 2]) > 3.0  # (in the hold: 8-10 s)


def test_a_command_held_at_zero_stays_zero_whatever_the_energy():
    """Damping is a force too: while the gate holds the force off, the controller only observes."""
    controller = PassivityController(max_damping=1.0)  # (capped: the energy gets through)
    v = np.array([0.0, 0.0, 0.05])
    controller.apply(np.array([0.0, 0.0, 2.0]), v, DT)
    controller.apply(np.array([0.0, 0.0, 2.0]), v, DT)  # (the first tick accounted: E > 0 now)
    assert controller.energy_J > 5e-5
    zero = np.zeros(3)
    assert not controller.apply(zero, v, DT, add=False).any() and controller.damping == 0.0
