"""A reading that jumps faster than any contact is held out until it is back; one that stays is a bias step."""

from __future__ import annotations

import numpy as np

from hapticlab.sessions.live.watch import MAX_CONTACT_RATE, STEP_MARGIN_N, STEP_PERSIST_NS, StepWatch

MS = 1_000_000


def readings(seconds: float, rate_hz: float, seed: int = 0, noise: float = 0.12):
    """A pressing contact (0 → 3 N over 0.3 s, raised cosine) along z plus Gamma-class noise, N."""
    rng = np.random.default_rng(seed)
    t_ns = (np.arange(int(seconds * rate_hz)) * (1e9 / rate_hz)).astype(np.int64)
    t = t_ns * 1e-9
    contact = 1.5 * (1 - np.cos(np.pi * np.clip(t / 0.3, 0, 1)))
    force = np.zeros((len(t), 3))
    force[:, 2] = contact
    return t_ns, force + rng.normal(0.0, noise, force.shape)


def feed(watch: StepWatch, t_ns, force, block: int = 7):
    return np.concatenate([watch.add(t_ns[k : k + block], force[k : k + block]) for k in range(0, len(t_ns), block)])


def test_a_real_contact_and_the_noise_are_never_held_out():
    for rate_hz, seed in ((1000.0, 1), (7000.0, 2)):
        t_ns, force = readings(3.0, rate_hz, seed)
        watch = StepWatch()
        assert not feed(watch, t_ns, force).any() and watch.jump == "" and watch.sudden == ""


def test_a_60_n_glitch_is_held_out_from_its_first_sample_to_its_end():
    t_ns, force = readings(1.0, 1000.0, 3)
    force[500:530, 0] += 60.0  # 30 ms within a 65 N range, good status
    watch = StepWatch()
    held = feed(watch, t_ns, force)
    assert np.array_equal(np.flatnonzero(held), np.arange(500, 530))
    assert watch.persisted is None and watch.jump == ""  # back, and no bias step


def test_a_glitch_that_comes_back_only_part_way_leaves_a_sudden_step():
    """A 60 N glitch for 30 ms that returns 2.5 N off where it was: back (its samples go on), but the leftover,
    beyond the noise's margin, is a doubt for the gate (a contact moved meanwhile, or the sensor's zero did)."""
    t_ns, force = readings(1.0, 1000.0, 6)
    force[500:530, 0] += 60.0
    force[530:, 0] += 2.5
    watch = StepWatch()
    held = feed(watch, t_ns, force)
    assert np.array_equal(np.flatnonzero(held), np.arange(500, 530))
    assert watch.persisted is None and watch.sudden.endswith("N left when a jump came back")


def test_a_jump_that_stays_is_handed_over_as_a_bias_step():
    t_ns, force = readings(1.0, 1000.0, 4)
    force[400:, 1] += 20.0  # a knock: 20 N, for good
    watch = StepWatch()
    held = feed(watch, t_ns, force, block=1)
    after = np.flatnonzero(held)
    assert after[0] == 400 and len(after) == STEP_PERSIST_NS // MS  # held out until it had stayed 200 ms
    np.testing.assert_allclose(watch.persisted, [0.0, 20.0, 0.0], atol=0.6)  # the step, in S
    assert not held[400 + STEP_PERSIST_NS // MS :].any()  # then the new level is the reading's


def test_a_2_n_step_is_sudden_but_not_held_out_and_a_fast_press_is_neither():
    """2 N in 1 ms is faster than soft tissue pushes (100 N/s) and slower than a glitch (2000 N/s): said, not held
    (it may be a hard contact); a press of 3 N over 50 ms (~94 N/s at its steepest) is a contact's."""
    t_ns, force = readings(1.0, 1000.0, 4)
    force[600:, 1] += 2.0
    watch = StepWatch()
    assert not feed(watch, t_ns, force).any()
    assert watch.sudden.startswith("2.") and watch.sudden.endswith("N in 1 ms") and watch.jump == ""
    t = t_ns * 1e-9
    press = np.zeros_like(force)
    press[:, 0] = 1.5 * (1 - np.cos(np.pi * np.clip((t - 0.5) / 0.05, 0, 1)))
    watch = StepWatch()
    assert not feed(watch, t_ns, readings(1.0, 1000.0, 5)[1] + press).any() and watch.sudden == ""


def test_the_sudden_band_is_soft_tissue_s_rate_plus_the_noise_margin():
    """SUDDEN_RATE (100 N/s) counts where samples are far apart: 2 N between two samples of a 100 Hz sensor
    (2.5 N allowed) is a contact's, 3 N is sudden; at 1 kHz (1.6 N allowed) 2 N is sudden, 1.5 N is not."""
    for rate_hz, step, sudden in ((100.0, 2.0, False), (100.0, 3.0, True), (1000.0, 2.0, True), (1000.0, 1.5, False)):
        t_ns, force = readings(1.0, rate_hz, 0, noise=0.0)
        force = np.zeros_like(force)
        force[len(force) // 2 :, 0] = step
        watch = StepWatch()
        assert not feed(watch, t_ns, force).any()
        assert (watch.sudden != "") == sudden, (rate_hz, step, watch.sudden)


def test_the_limit_grows_with_the_time_between_samples():
    """After a 0.5 s gap (a dropout) a contact may have moved by MAX_CONTACT_RATE·0.5 s: no jump."""
    watch = StepWatch()
    assert not watch.add(np.array([0, MS]), np.zeros((2, 3))).any()
    far = MAX_CONTACT_RATE * 0.5 + STEP_MARGIN_N - 1.0
    assert not watch.add(np.array([MS + 500 * MS]), np.array([[far, 0.0, 0.0]])).any()
    assert watch.add(np.array([MS + 501 * MS]), np.array([[far + 10.0, 0.0, 0.0]])).all()


def test_a_stuck_sensor_is_held_out_once_it_has_repeated_itself_for_50_ms():
    from hapticlab.sessions.live.watch import STUCK_NS, StuckWatch

    t_ns, force = readings(1.0, 1000.0, 5)
    torque = np.zeros_like(force) + np.random.default_rng(6).normal(0, 0.01, force.shape)
    force[300:500], torque[300:500] = force[300], torque[300]  # 200 ms of one reading, fresh stamps
    watch = StuckWatch()
    held = np.concatenate([watch.add(t_ns[k : k + 7], force[k : k + 7], torque[k : k + 7]) for k in range(0, 1000, 7)])
    assert np.array_equal(np.flatnonzero(held), np.arange(300 + STUCK_NS // MS, 500))
    assert watch.stuck_ns == 0  # the readings move again
    clean_t, clean_f = readings(3.0, 7000.0, 7)
    assert not StuckWatch().add(clean_t, clean_f, np.zeros_like(clean_f) + 1e-3 * clean_f).any()
