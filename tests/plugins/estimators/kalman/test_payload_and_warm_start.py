"""``kalman``: payload changes without contact, and warm starts from a saved state.

Simulated at 1 kHz with Table I's noise (0.12 N, 0.01 N·m per axis), the paper's
tool (0.2 kg) and bias; run with ``-s`` to see the measured numbers.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from hapticlab.plugins.estimators.kalman import IDENTIFICATION_EVENTS, KalmanEstimator
from hapticlab.sessions.bench.paper_setup import PaperSetup
from hapticlab.sessions.bench.simulation import feed, simulate

NOISE = {"noise_force": 0.12, "noise_torque": 0.01}
DRIFT_FORCE = [0.5 / 60.0 / math.sqrt(2), 0.5 / 60.0 / math.sqrt(2), 0.0]  # 0.5 N/min, N/s
TOUR = {"script": "random_tour", "max_tilt_deg": 60.0, "segment_s": 3.0}
RATE_HZ = 1000.0


def world(contacts=None, seconds=30.0, seed=2025, mass=0.2, **sensor):
    sim = PaperSetup(seed=seed, mass=mass).world(TOUR, contacts, **{**NOISE, **sensor})
    return simulate(sim, seconds, RATE_HZ)


def payload(start, mass=0.1):
    """A mass hung on the tool from ``start`` on and never removed: a payload change, no contact."""
    return [{"kind": "hanging_mass", "start": start, "duration": 1e9, "mass": mass}]


def indentations(seconds):
    """A 3 N indentation every 10 s, 2 s long (0.4 s ramps), straight up in B (along gravity)."""
    return [
        {"kind": "indentation", "start": 5.0 + 10.0 * k, "duration": 2.0, "peak_force": 3.0, "ramp": 0.4}
        for k in range(int(seconds // 10))
    ]


def reconverged_after(block, flags, t_ns):
    """Samples after t_ns until the flags are up and stay up; None if never."""
    after = np.flatnonzero(block.t_ns > t_ns)
    up = flags[after]
    if not up[-1]:
        return None
    down = np.flatnonzero(~up)
    return 0 if len(down) == 0 else int(down[-1]) + 1


def close_to(a, b, force=0.02, cog=0.003):
    return (
        np.abs(np.subtract(a["gravity_force_B"], b["gravity_force_B"])).max() < force
        and np.abs(np.subtract(a["cog_S"], b["cog_S"])).max() < cog
    )


@pytest.fixture(scope="module")
def reference_heavy():
    """The parameters of the tool with the 100 g mass, identified from a cold start in the payload test's world
    (its drift too). Since 2026-11-28 the defaults learn a tilt walk, and the drift, faster than the bias's walk
    over time, is learnt as one (0.013 N/√rad; docs/estimators.md, "The tilt walk"): the torque bias's share
    of it slows the centre of gravity along the tool, weakly identified on this ±60° tour, from a cold start as
    after a payload change (cog_z 106.7 mm at 30 s against 108.8 without the drift; 112.3 the truth). Before,
    the reference had no drift: without a walk the two differ by 0.06 mm (108.77 and 108.83)."""
    block, _ = world(payload(0.0), seconds=30.0, drift_force=DRIFT_FORCE)
    est = KalmanEstimator()
    feed(est, block, chunk=64)
    return est.params()


def others(est) -> list:
    """The estimator's events but for what the motion identified (``identified``; the identified rule's)."""
    return [e for e in est.events if e.kind not in IDENTIFICATION_EVENTS]


# ---------------------------------------------------------------- payload change


@pytest.mark.parametrize("rule", ["covariance", "identified"])
def test_added_mass_is_a_payload_change_and_reconverges(reference_heavy, rule):
    start = 20.0
    block, _ = world(payload(start), seconds=30.0, drift_force=DRIFT_FORCE)
    est = KalmanEstimator(convergence=rule)
    out, _ = feed(est, block, chunk=64)
    events = est.drain_events()
    # with the identified rule, first the weight and the centre of mass identified by the motion (one event each)
    expected = ["identified", "identified", "payload_change"] if rule == "identified" else ["payload_change"]
    assert [e.kind for e in events] == expected and est.drain_events() == []
    t_event = events[-1].t_ns
    delay = (t_event - block.t_ns[0]) * 1e-9 - start
    hung_ns = block.t_ns[0] + int(start * 1e9)
    force = reconverged_after(block, out.converged_force, hung_ns)
    torque = reconverged_after(block, out.converged_force & out.converged_torque, t_event)
    print(
        f"\npayload change of 100 g: recognised and the new weight identified {delay:.3f} s after the "
        f"mass was hung (until then its weight is reported as contact); the force stage's flag was up "
        f"again {force / RATE_HZ:.3f} s after the hang, the torque stage's {torque / RATE_HZ:.3f} s after "
        f"the event (the new centre of gravity needs the tool to turn); {events[0].message}"
    )
    assert 0.3 <= delay < 0.5  # the target (re-converged within 0.5 s): payload_change_s + a block
    assert force is not None and force / RATE_HZ <= 0.5
    assert torque is not None and torque / RATE_HZ <= 1.0
    assert close_to(est.params(), reference_heavy), (est.params(), reference_heavy)
    after = block.t_ns > t_event
    assert np.mean(out.contact[after]) < 0.001  # the extra weight is no longer taken for contact
    rms = np.sqrt(np.mean(out.contact_force_S[after] ** 2, axis=0))
    assert np.all(rms < 1.1 * NOISE["noise_force"]), rms


@pytest.mark.parametrize("rule", ["covariance", "pose"])
def test_what_the_learnt_walk_costs_the_centre_of_gravity_under_a_drift(rule):
    """The price of the learnt tilt walk (the default since 2026-11-28) for the torque stage: a 0.5 N/min drift,
    faster than the bias's walk over time, is learnt as walk (0.013 N/√rad), the torque bias walks with it
    (5/65), and the centre of gravity along the tool, which this ±60° tour identifies weakly, comes slower: 10 s
    after a 100 g payload change, cog_z is 3–5 mm short of where the walk off puts it (truth 112.3 mm; the walk
    off is 3 mm short of it, from the cold start on). Pinned here so it cannot grow unseen; the payload test
    above compares with a cold start that pays it too."""
    block, _ = world(payload(20.0), seconds=30.0, drift_force=DRIFT_FORCE)
    cog = {}
    for label, options in (("walk off", {"bias_force_tilt_rw": 0.0}), ("defaults", {})):
        est = KalmanEstimator(convergence=rule, **options)
        feed(est, block, chunk=64)
        cog[label] = est.params()["cog_S"][2] * 1000.0
    print(f"\n{rule}: cog_z 10 s after the payload change, mm: { ({k: round(v, 2) for k, v in cog.items()}) }")
    assert abs(cog["walk off"] - 112.3) <= 4.0
    assert abs(cog["defaults"] - cog["walk off"]) <= 5.0


def test_indentations_are_not_payload_changes():
    block, _ = world(indentations(180.0), seconds=180.0, drift_force=DRIFT_FORCE)
    est = KalmanEstimator()
    out, _ = feed(est, block, chunk=64)
    print(f"\n18 indentations of 2 s: {len(est.events)} payload changes, {int(out.contact.sum())} samples refused")
    assert others(est) == []
    assert out.contact.sum() > 18 * 1000  # the indentations were refused as contact


@pytest.mark.parametrize(
    ("peak", "start", "noise"),
    [(0.8, 5.0, NOISE), (1.0, 5.0, {}), (1.5, 5.0, NOISE), (3.0, 1.0, {})],
    ids=[
        "0.8 N, the noise given",
        "1 N, auto noise",
        "1.5 N, the noise given",
        "3 N from the first second, auto noise",
    ],
)
def test_indentations_2_s_in_every_4_are_not_payload_changes(peak, start, noise):
    """Closer indentations, whose refusal runs begin where the ramp crosses the gate (about half way up) and
    whose window, grown past the ramp, fits a weight change to within the noise estimate. Before the onset
    test (``plugins.estimators.kalman.payload.ONSET_SHARE``) they were, each time re-opening gravity: 1.5 N ones 4
    times, and the contact force where both flags were up was 0.32 / 0.34 / 0.83 N off (RMS); 3 N ones from the first
    second, with the noise estimated, 5 times, 0.36 / 0.50 / 0.83 N. Lighter ones, whose plateau is near the
    gate, passed an onset of refused samples only (those the noise pushed over the gate)."""
    touches = [
        {"kind": "indentation", "start": start + 4.0 * k, "duration": 2.0, "peak_force": peak, "ramp": 0.4}
        for k in range(int((20.0 - start) // 4.0))
    ]
    block, truth = world(touches, seconds=20.0)
    est = KalmanEstimator(**noise)
    out, _ = feed(est, block, chunk=64)
    known = out.converged_force & out.converged_torque
    error = np.sqrt(np.mean((out.contact_force_S - truth["contact_force_S"])[known] ** 2, axis=0))
    print(
        f"\n{peak} N indentations 2 s in every 4: {len(others(est))} payload changes, error where both flags "
        f"are up {np.round(error, 3)} N"
    )
    assert others(est) == []
    assert np.all(error < 0.2), error  # (0.8 N ones are partly under the gate: 0.14–0.18 N)


def test_a_run_that_begins_below_its_plateau_is_not_a_payload_change():
    """The watch on its own, fed refused runs that fit a weight change along gravity equally well once the
    window is full: a step (a mass hung at once) is named; a ramp from half its plateau to it over the first
    0.1 s, then held, is not, though its window's fit passes (its onset, the first 30 ms, carries 0.57 of the
    change)."""
    from scipy.spatial.transform import Rotation

    from hapticlab.plugins.estimators.kalman import payload as pl

    rng = np.random.default_rng(11)
    m = 900  # 0.9 s at 1 kHz: the whole window
    t_ns = 10**9 + np.arange(m) * 10**6
    A = Rotation.from_rotvec(np.outer(np.linspace(0.0, 0.3, m), [1.0, 0.0, 0.0])).as_matrix()  # a slow turn
    g = np.array([0.0, 0.0, -1.96])
    r = np.full(3, 0.12**2)
    named = {}
    for label, level in (("step", np.ones(m)), ("ramp", np.minimum(0.5 + 5.0 * np.arange(m) * 1e-3, 1.0))):
        e = (A @ (0.5 * g)) * level[:, None] + rng.normal(0.0, 0.12, (m, 3))
        watch = pl.PayloadWatch(300_000_000)
        window = pl.RefusedWindow()
        window.append(e=e, A=A, y=e, f=e, tq=e, R=A)
        dg, ratio = window.fit(r)
        named[label] = None
        for k in range(0, m, 64):  # ticks of 64 samples, every one refused, until the first change named
            tick = slice(k, k + 64)
            refused = np.ones(len(t_ns[tick]), dtype=bool)
            named[label] = watch.observe(
                t_ns[tick], refused, refused, e[tick], A[tick], e[tick], e[tick], e[tick], A[tick], r, g
            )
            if k == 0:
                share = watch.onset_share(dg)  # (its 30 ms are in the first tick)
            if named[label] is not None:
                break
        print(
            f"\n{label}: full window's fit ratio {ratio:.2f}, onset share {share:.2f}, named {named[label] is not None}"
        )
        assert ratio < pl.FIT_RATIO  # the fit alone would pass both
    assert named["step"] is not None and named["ramp"] is None
    assert abs(named["step"].weight_change - 0.98) < 0.05


def test_a_step_while_the_flange_goes_into_it_is_a_touch_not_a_payload():
    """The same step along gravity, at one orientation (teleoperation holds it): with the flange still it is a
    payload; with the flange going 0.3 mm down while the force pushes up (a tool pressed into tissue), or up
    while the sensor grows heavier (lifted off a support), it is a touch, never named; a flange going with the
    change (a payload hung while the arm lowers) is still a payload."""
    from hapticlab.plugins.estimators.kalman import payload as pl

    rng = np.random.default_rng(5)
    m = 400
    t_ns = 10**9 + np.arange(m) * 10**6
    A = np.repeat(np.eye(3)[None], m, axis=0)
    g = np.array([0.0, 0.0, -1.96])
    r = np.full(3, 0.05**2)
    down = np.outer(np.linspace(0.0, -3e-4, m), [0.0, 0.0, 1.0]) + [0.45, 0.0, 0.35]  # 0.3 mm down over the run

    def named(change_B, p):
        e = change_B + rng.normal(0.0, 0.05, (m, 3))
        watch = pl.PayloadWatch(300_000_000)
        for k in range(0, m, 32):
            tick, refused = slice(k, k + 32), np.ones(len(t_ns[k : k + 32]), dtype=bool)
            found = watch.observe(
                t_ns[tick], refused, refused, e[tick], A[tick], e[tick], e[tick], e[tick], A[tick], r, g, p[tick]
            )
            if found is not None:
                return True
        return False

    still = np.repeat(down[:1], m, axis=0)
    up, heavier = np.array([0.0, 0.0, 1.4]), np.array([0.0, 0.0, -1.4])
    assert named(up, still) and named(heavier, still)  # nothing moved: a weight change either way
    assert not named(up, down)  # pressed in: the tissue pushes back
    assert not named(heavier, down[::-1])  # lifted off what held it up
    assert named(heavier, down)  # a mass hung as the arm lowers: the flange goes with the change


def test_a_payload_whose_weight_comes_on_within_50_ms_is_still_named():
    """The onset test's price, bounded: 100 g whose weight comes on over 50 ms (a mass dropped onto a hook) still
    begins its run with nearly all of it, and is named. (Over 0.1 s it is on 1 seed of 5, over 0.2 s on none:
    docs/estimators.md.)"""
    down = [
        {
            "kind": "indentation",
            "start": 5.0,
            "duration": 1e9,
            "peak_force": 0.1 * 9.81,
            "ramp": 0.05,
            "direction_B": [0.0, 0.0, -1.0],
        }
    ]
    block, _ = world(down, seconds=10.0)
    est = KalmanEstimator()
    feed(est, block, chunk=64)
    changes = [e for e in others(est) if e.kind == "payload_change"]
    assert len(changes) == 1 and 5.0 < (changes[0].t_ns - block.t_ns[0]) * 1e-9 < 5.5, others(est)


def test_payload_change_can_be_disabled():
    block, _ = world(payload(5.0), seconds=10.0)
    est = KalmanEstimator(payload_change_s=0)
    out, _ = feed(est, block, chunk=64)
    assert others(est) == [] and out.contact[block.t_ns > 6.5e9].mean() > 0.99


def test_payload_option_is_checked():
    for bad in (-1.0, math.nan, "1"):
        with pytest.raises(ValueError, match="payload_change_s"):
            KalmanEstimator(payload_change_s=bad)


# ---------------------------------------------------------------- warm start


@pytest.fixture(scope="module")
def saved_state(tmp_path_factory):
    """The state after a 20 s simulated session with the paper's tool, saved as JSON."""
    block, _ = world(seconds=20.0, seed=2025)
    est = KalmanEstimator()
    feed(est, block, chunk=64)
    assert est.converged_force and est.converged_torque
    path = tmp_path_factory.mktemp("warm") / "previous.calibration.json"
    path.write_text(json.dumps(est.state()))
    return path, est


def test_state_is_json_and_round_trips(saved_state):
    path, est = saved_state
    state = json.loads(path.read_text())
    assert state["estimator"] == "kalman" and state["converged_force"] and state["converged_torque"]
    assert isinstance(state["t_ns"], int)
    warm = KalmanEstimator(warm_start=str(path))
    assert np.array_equal(warm.force.x, est.force.x) and np.array_equal(warm.force.P, est.force.P)
    assert np.array_equal(warm.torque.x, est.torque.x) and np.array_equal(warm.torque.P, est.torque.P)


def test_a_state_saved_with_the_physical_torque_bias_is_converted_on_loading(saved_state, tmp_path):
    """A state saved before the torque stage's bias was about the measured force holds [cog_S, bias_torque_S],
    its P and its information in those coordinates and no ``torque_bias`` key: loaded, it is the same estimator
    as the state saved now (x, P and the torque information through J = [[I, 0], [[bias_force_S]×, I]])."""
    from hapticlab.core.frames import skew

    path, est = saved_state
    state = json.loads(path.read_text())
    J = np.eye(6)
    J[3:6, :3] = skew(np.array(state["force"]["x"][3:6]))
    x, P = np.array(state["torque"]["x"]), np.array(state["torque"]["P"])
    x_phys, P_phys = np.linalg.solve(J, x), np.linalg.solve(J, np.linalg.solve(J, P).T)  # J⁻¹ x, J⁻¹ P J⁻ᵀ
    old = dict(state, torque={"x": x_phys.tolist(), "P": P_phys.tolist()})
    old["information"] = dict(
        state["information"], torque=(J.T @ np.array(state["information"]["torque"]) @ J).tolist()
    )
    del old["torque_bias"]
    assert np.allclose(x_phys[3:6], est.params()["bias_torque_S"], rtol=1e-12, atol=1e-15)  # physical, as reported
    (tmp_path / "old.json").write_text(json.dumps(old))
    now, before = KalmanEstimator(warm_start=str(path)), KalmanEstimator(warm_start=str(tmp_path / "old.json"))
    assert np.allclose(before.torque.x, now.torque.x, rtol=1e-12, atol=1e-15)
    assert np.allclose(before.torque.P, now.torque.P, rtol=1e-9, atol=1e-18)
    assert np.allclose(before._information["torque"], now._information["torque"], rtol=1e-9)
    assert before.params()["bias_torque_S"] == pytest.approx(now.params()["bias_torque_S"], rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("rule", ["covariance", "identified"])
def test_warm_start_with_the_same_tool_converges_at_once(saved_state, rule):
    path, _ = saved_state
    block, _ = world(seconds=10.0, seed=7)  # another session: other motion and noise, same tool and sensor
    warm, cold = KalmanEstimator(warm_start=str(path), convergence=rule), KalmanEstimator(convergence=rule)
    out, _ = feed(warm, block, chunk=64)
    feed(cold, block, chunk=64)
    print(
        f"\nwarm start, same tool: converged at sample {warm.first_converged_force} (force), "
        f"{warm.first_converged_torque} (torque); cold start: {cold.first_converged_force}, "
        f"{cold.first_converged_torque}"
    )
    assert warm.first_converged_force < 10 and warm.first_converged_torque < 10
    assert others(warm) == [] and out.contact.mean() < 0.001
    rms = np.sqrt(np.mean(out.contact_force_S**2, axis=0))
    assert np.all(rms < 1.1 * NOISE["noise_force"]), rms


@pytest.mark.parametrize("rule", ["covariance", "identified"])
def test_warm_start_with_a_changed_tool_recovers(saved_state, rule):
    path, _ = saved_state
    block, _ = world(seconds=10.0, seed=7, mass=0.3)  # a 100 g heavier tool since the saved session
    warm = KalmanEstimator(warm_start=str(path), convergence=rule)
    out, _ = feed(warm, block, chunk=64)
    events = [e for e in warm.drain_events() if e.kind not in IDENTIFICATION_EVENTS]
    assert [e.kind for e in events] == ["payload_change"]
    t_event = events[0].t_ns
    force = reconverged_after(block, out.converged_force, block.t_ns[0])
    torque = reconverged_after(block, out.converged_force & out.converged_torque, t_event)
    print(
        f"\nwarm start, tool 100 g heavier: payload change recognised at "
        f"{(t_event - block.t_ns[0]) * 1e-9:.3f} s; force stage converged for good at "
        f"{force / RATE_HZ:.3f} s, torque stage {torque / RATE_HZ:.3f} s after the event"
    )
    assert (t_event - block.t_ns[0]) * 1e-9 < 0.5
    assert force is not None and force / RATE_HZ <= 0.5
    assert torque is not None and torque / RATE_HZ <= 1.5
    assert abs(warm.params()["gravity_force_B"][2] - (-0.3 * 9.81)) < 0.05


def test_warm_start_refuses_other_estimators_and_corrupt_files(tmp_path, saved_state):
    path, est = saved_state
    state = est.state()
    cases = {
        "other.json": json.dumps({**state, "estimator": "rls"}),
        "corrupt.json": "{not json",
        "shape.json": json.dumps({**state, "force": {"x": [0.0] * 5, "P": state["force"]["P"]}}),
        "nan.json": json.dumps({**state, "torque": {"x": [float("nan")] * 6, "P": state["torque"]["P"]}}),
        "notpd.json": json.dumps({**state, "force": {"x": state["force"]["x"], "P": (-np.eye(6)).tolist()}}),
        "list.json": "[1, 2]",
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=r"^warm_start: "):
            KalmanEstimator(warm_start=str(tmp_path / name))
    with pytest.raises(ValueError, match=r"^warm_start: cannot read"):
        KalmanEstimator(warm_start=str(tmp_path / "missing.json"))
    with pytest.raises(ValueError, match=r"^warm_start: .*bias_rate"):
        KalmanEstimator(warm_start=str(path), bias_rate=True)


@pytest.mark.parametrize("chunk", [64, 5000])
def test_a_held_contact_is_not_a_payload_change(chunk):
    # 3 N straight up in B held for 15 s: constant along gravity like a lighter tool, but it ramps up
    contact = [{"kind": "indentation", "start": 20.0, "duration": 15.0, "peak_force": 3.0, "ramp": 0.4}]
    block, _ = world(contact, seconds=40.0)
    est = KalmanEstimator()
    feed(est, block, chunk=chunk)
    assert others(est) == []


def test_the_refused_window_grows_and_fits_as_the_least_squares_over_it():
    """The payload test's window: appended a tick at a time past its capacity, it keeps every sample in
    order, and its running-sum fit equals the least squares of e = R_SB·Δg + residual over the stacked
    window (np.linalg.lstsq on the stacked (3m, 3) system)."""
    from scipy.spatial.transform import Rotation

    from hapticlab.plugins.estimators.kalman.payload import RefusedWindow

    rng = np.random.default_rng(7)
    R = Rotation.random(50, random_state=8).as_matrix()
    dg_true = np.array([0.0, 0.0, -0.98])
    e = R @ dg_true + rng.normal(0.0, 0.05, (50, 3))
    window = RefusedWindow(capacity=4)
    for k in range(0, 50, 3):  # blocks of 3 (and a last of 2): the buffers double several times
        part = slice(k, k + 3)
        window.append(e=e[part], A=R[part], y=e[part] + 1.0, f=e[part] + 2.0, tq=e[part] + 3.0, R=R[part])
    stacked = window.window()
    assert len(window) == 50 and np.array_equal(stacked["e"], e) and np.array_equal(stacked["R"], R)
    assert np.array_equal(stacked["tq"], e + 3.0)
    r = np.array([0.05, 0.04, 0.06]) ** 2
    dg, ratio = window.fit(r)
    dg_ls, *_ = np.linalg.lstsq(R.reshape(-1, 3), e.reshape(-1), rcond=None)
    assert np.allclose(dg, dg_ls, atol=1e-12)
    assert np.isclose(ratio, np.mean((e - R @ dg_ls) ** 2 / r), rtol=1e-9)
    assert np.linalg.norm(dg - dg_true) < 0.03


def test_a_warm_start_carries_a_quiet_sensor_s_noise_so_light_touches_from_the_first_second_are_refused(tmp_path):
    """The remedy for a cold start's blind spot (docs/estimators.md, "Auto noise"): on a quiet sensor (0.01 N) the
    auto noise estimate starts at 0.5 N and comes down over seconds (0.12 N after 1 s of free motion), so 0.5 N
    touches from the first second pass the gate and are taken into it; from a cold start their contact force is
    then 0.13 / 0.18 / 0.26 N off. A state saved after a free session with the same sensor starts the estimate
    where it was: the gate refuses the touches and the contact force is the measured one."""
    quiet = {"noise_force": 0.01, "noise_torque": 0.001}
    free, _ = world(seconds=20.0, seed=7, **quiet)
    calibration = KalmanEstimator()
    feed(calibration, free, chunk=64)
    path = tmp_path / "quiet.calibration.json"
    path.write_text(json.dumps(calibration.state()))
    touches = [
        {"kind": "indentation", "start": 1.0 + 4.0 * k, "duration": 2.0, "peak_force": 0.5, "ramp": 0.4}
        for k in range(8)
    ]
    block, truth = world(touches, seconds=30.0, **quiet)
    touching = np.asarray(truth["contact"], dtype=bool)
    results = {}
    for label, options in (("cold", {}), ("warm", {"warm_start": str(path)})):
        out, _ = feed(KalmanEstimator(**options), block, chunk=64)
        error = np.sqrt(np.mean((out.contact_force_S - truth["contact_force_S"])[touching] ** 2, axis=0))
        results[label] = (error, out.contact[touching].mean())
        print(f"\n{label} start: in-contact error {np.round(error, 3)} N, judged contact {results[label][1]:.2f}")
    error, judged = results["warm"]
    assert np.all(error < 0.04) and judged > 0.8, results
