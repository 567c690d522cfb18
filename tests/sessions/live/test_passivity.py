"""Force feedback that stays passive: the port's observer and controller, the simulated master and hand, and the
closed loop hand → master → robot → stiff tissue → force → hand with a delay on the link."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.core.errors import ConfigError
from hapticlab.core.types import HapticCommand
from hapticlab.plugins.haptics.sim_master import SimMaster
from hapticlab.sessions.config import apply_settings, load_config
from hapticlab.sessions.live import build_session
from hapticlab.sessions.live.passivity import PassivityController
from hapticlab.sessions.live.safety import ForceGovernor
from hapticlab.sessions.recording import read_recording
from hapticlab.sessions.settings import HapticSettings

DT = 0.001


def drive(master: SimMaster, force, seconds: float, controller: PassivityController | None = None) -> np.ndarray:
    """Run ``master`` 1 kHz for ``seconds`` with ``force(p, v)`` (N, in D) through ``controller`` as the loop runs
    it (observe, damp, hold); the energy the port put into the hand, J, tick by tick, accounted here: each force
    sent times the velocity its tick ended at."""
    energy, total, sent = [], 0.0, None
    for k in range(round(seconds / DT)):
        state = master.state()
        if sent is not None:
            total += float(sent @ state.v_DHo_D) * DT
        energy.append(total)
        f = np.asarray(force(state.p_DoHo_D, state.v_DHo_D), dtype=float)
        if controller is not None:
            controller.observe(state.v_DHo_D, DT if k else 0.0)
            f = np.array(controller.damp(f.tolist()))
            controller.hold(f)
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
    controller.observe(np.array([0.0, 0.0, 0.01]), DT)
    out = controller.damp([0.0, 0.0, 10.0])  # 1e-4 J to take out: α = 1000 wanted
    assert controller.damping == 5.0 and out[2] == pytest.approx(10.0 - 5.0 * 0.01)
    controller.observe(np.array([0.0, float("nan"), 0.0]), DT)  # (a velocity not known: nothing accounted)
    assert controller.damp([0.0, 0.0, 1.0]) == [0.0, 0.0, 1.0] and controller.damping == 0.0
    assert np.isfinite(controller.energy_J)


def test_a_command_held_at_zero_stays_zero_whatever_the_energy():
    """Damping is a force too: the governor asks the port only for a force it may render, never for a zero."""
    governor = ForceGovernor(HapticSettings(), 0.001)
    asked = []
    zero = governor.command(0, np.array([0.0, 0.0, 2.0]), np.eye(3), reason="no sensor data", port=asked.append)
    assert not zero.force_D.any() and not zero.enabled and asked == []


def test_the_port_s_damping_is_clamped_and_rate_limited_like_any_force():
    governor = ForceGovernor(HapticSettings(max_force=4.0, max_force_rate=400.0), 0.001)
    command = governor.command(0, np.array([0.0, 0.0, 0.1]), np.eye(3), port=lambda f: [0.0, 0.0, 50.0])
    assert command.force_D[2] == pytest.approx(0.4)  # one 1 ms step of 400 N/s, not 50 N


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
    # what the master was sent, damping included: zero while the force is off, within the limit, rate-limited
    enabled = np.array([m["enabled"] for _, m in rec.topics["/haptic/command"][:-1]])
    size = np.linalg.norm(force, axis=1)
    assert not force[~enabled].any() and size.max() <= 4.0 + 1e-9
    step = np.linalg.norm(np.diff(force, axis=0), axis=1)
    assert np.all((step <= 0.4 + 1e-9) | (size[1:] < size[:-1]))  # 400 N/s at 1 kHz, or going down
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


def test_a_delayed_link_is_for_the_simulated_master_only():
    """The gate's zero crosses the link too: with a real device on the other end it would reach the hand late."""
    config, _ = load_config("teleop-sim")
    config = apply_settings(config, {"teleop.delay_s": 0.1, "haptic.name": "null"})
    config["haptic"] = {k: v for k, v in config["haptic"].items() if k not in ("press_at", "depth", "ramp", "hold")}
    with pytest.raises(ConfigError, match=r"teleop.delay_s: a delayed link is simulated with the simulated master"):
        build_session(config)
