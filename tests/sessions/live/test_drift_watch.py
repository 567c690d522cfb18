"""A residual that keeps its direction in the sensor while the tool turns is the sensor's (or the estimator's
bias); one that keeps it in the world is a contact; a tool that does not turn tells nothing."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hapticlab.sessions.live.drift import BIN_NS, WINDOW_BINS, DriftWatch

RATE_HZ = 1000.0
NOISE_N = 0.12  # per axis, the simulated sensor's default (Gamma class)


def turning(seconds: float, rad_s: float, axis=(1.0, 0.0, 0.0)):
    """Stamps (ns) and R_EB of a tool turning at ``rad_s`` about ``axis`` (in B)."""
    t_ns = (np.arange(int(seconds * RATE_HZ)) * (1e9 / RATE_HZ)).astype(np.int64)
    rotvec = np.outer(t_ns * 1e-9 * rad_s, np.asarray(axis) / np.linalg.norm(axis))
    return t_ns, Rotation.from_rotvec(rotvec).as_matrix()  # R_EB: B seen from E (= S, no mount)


def verdicts(t_ns, R_EB, residual_S, block: int = 3):
    """Every verdict the watch gives, with its stamp (s), fed in live-sized blocks."""
    watch, out = DriftWatch(), []
    for k in range(0, len(t_ns), block):
        v = watch.add(t_ns[k : k + block], residual_S[k : k + block], R_EB[k : k + block], None)
        if v:
            out.append((t_ns[k] * 1e-9, v))
    return out


def noise(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, NOISE_N, (n, 3))


def test_an_offset_fixed_in_the_sensor_is_the_sensor_s_once_the_tool_has_turned():
    t_ns, R_EB = turning(3.0, 1.0)
    residual = noise(len(t_ns), 1) + [0.0, 1.0, 0.0]  # 1 N along S's y, the tool turning about x
    found = verdicts(t_ns, R_EB, residual)
    assert found and all(v == "sensor" for _, v in found)
    assert found[0][0] <= WINDOW_BINS * BIN_NS * 1e-9 + 0.05  # as soon as the first window is full


def test_a_drift_is_told_while_it_is_still_small():
    t_ns, R_EB = turning(4.0, 1.0)
    residual = noise(len(t_ns), 2)
    residual[:, 1] += 0.5 * t_ns * 1e-9  # 0.5 N/s, the bench's ramp
    found = verdicts(t_ns, R_EB, residual)
    assert found and found[0][1] == "sensor" and found[0][0] <= 1.2  # by then the drift is 0.6 N


def test_a_contact_fixed_in_the_world_is_never_the_sensor_s():
    for seed, peak in ((3, 0.5), (4, 1.0), (5, 4.0)):
        t_ns, R_EB = turning(4.0, 1.0)
        t = t_ns * 1e-9
        magnitude = peak * 0.5 * (1 - np.cos(np.pi * np.clip((t - 0.5) / 0.3, 0, 1)))  # pressed in over 0.3 s
        force_B = np.outer(magnitude, [0.0, 0.6, 0.8])
        residual = np.einsum("nij,nj->ni", R_EB, force_B) + noise(len(t), seed)
        found = verdicts(t_ns, R_EB, residual)
        assert found and {v for _, v in found} == {"world"}, (peak, found[:3])


def test_a_tool_that_does_not_turn_or_turns_about_the_force_tells_nothing():
    t_ns, R_EB = turning(3.0, 0.0)
    assert verdicts(t_ns, R_EB, noise(len(t_ns), 6) + [0.0, 1.0, 0.0]) == []
    t_ns, R_EB = turning(3.0, 1.0)
    assert verdicts(t_ns, R_EB, noise(len(t_ns), 7) + [1.0, 0.0, 0.0]) == []  # the turn's own axis


def test_noise_alone_is_never_a_verdict():
    t_ns, R_EB = turning(30.0, 1.0, axis=(1.0, 1.0, 0.0))
    assert verdicts(t_ns, R_EB, noise(len(t_ns), 8)) == []


def test_a_mounted_sensor_is_judged_in_its_own_frame():
    """S turned from E by the mount (R_SE): a bias fixed in S is the sensor's, a force fixed in B the world's."""
    R_SE = Rotation.from_euler("xyz", [0.3, -1.1, 0.7]).as_matrix()
    t_ns, R_EB = turning(3.0, 1.0)
    bias = noise(len(t_ns), 9) + R_SE @ [0.0, 1.0, 0.0]  # fixed in S (off the turn's axis, seen from E)
    watch = DriftWatch()
    found = {watch.add(t_ns[k : k + 3], bias[k : k + 3], R_EB[k : k + 3], R_SE) for k in range(0, len(t_ns), 3)}
    assert found == {"", "sensor"}
    R_SB = np.einsum("ij,njk->nik", R_SE, R_EB)
    contact = np.einsum("nij,j->ni", R_SB, [0.0, 0.6, 0.8]) + noise(len(t_ns), 10)
    watch = DriftWatch()
    found = {watch.add(t_ns[k : k + 3], contact[k : k + 3], R_EB[k : k + 3], R_SE) for k in range(0, len(t_ns), 3)}
    assert found == {"", "world"}


def test_a_bias_beside_a_contact_is_no_verdict_until_the_contact_has_gone():
    """The window then fits neither frame by noise alone: re-identifying there would take the contact in."""
    t_ns, R_EB = turning(4.0, 1.0)
    t = t_ns * 1e-9
    contact_B = np.outer(np.where(t < 2.5, 2.0, 0.0), [0.0, 0.6, 0.8])
    residual = np.einsum("nij,nj->ni", R_EB, contact_B) + [0.0, 1.0, 0.0] + noise(len(t), 11)
    found = verdicts(t_ns, R_EB, residual)
    assert not [v for s, v in found if v == "sensor" and s < 2.5]
    assert [v for s, v in found if s > 2.5] and all(v == "sensor" for s, v in found if s > 3.05)


def test_a_gap_in_the_samples_starts_the_window_afresh_and_infinities_are_skipped():
    t_ns, R_EB = turning(2.0, 1.0)
    residual = noise(len(t_ns), 12) + [0.0, 1.0, 0.0]
    residual[700] = np.inf
    watch = DriftWatch()
    assert watch.add(t_ns[:690], residual[:690], R_EB[:690], None) == "sensor"
    watch.add(t_ns[700:705], residual[700:705], R_EB[700:705], None)  # 10 ms later: no gap yet
    assert np.isfinite(watch.total).all() and watch.count == 4  # the infinite row left out
    later = t_ns[705:1100] + 100_000_000  # 100 ms withheld: the window starts again
    assert watch.add(later, residual[705:1100], R_EB[705:1100], None) == "" and watch.size == float("inf")
