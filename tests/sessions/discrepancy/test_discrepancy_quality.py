"""The data's own quality in the discrepancy workflow (``sessions/discrepancy/quality.py``, issue 43): a channel
that saturates, a channel read on a coarse grid.

Recordings are the lively 30 s, 250 Hz tour of ``test_discrepancy`` from the simulated world (seeds used
nowhere else), changed the way the sensor's electronics would: a channel clipped at a limit, every channel
rounded to an ADC step.
"""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.plugins.simworld import RandomTour, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.sessions.discrepancy.leftover import axis_noise
from hapticlab.sessions.discrepancy.workflow import discrepancy

AXES = ("fx", "fy", "fz", "tx", "ty", "tz")


def _set_column(path, column: str, change) -> np.ndarray:
    """Replace a CSV column by ``change(values)``; the other columns as written. Returns the new values."""
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    header = path.read_text().splitlines()[0].split(",")
    k = header.index(column)
    data[:, k] = change(data[:, k])
    np.savetxt(path, data, delimiter=",", header=",".join(header), comments="", fmt="%.10g")
    return data[:, k]


def quiet_world(seed: int, noise_force: float, noise_torque: float, mount=(0.0, 0.0, 0.0)) -> SimWorld:
    """A low-noise sensor (noise per axis in N and N·m) on the lively tour, the paper's static model."""
    return SimWorld(
        sensor=SensorParams(
            noise_force_S=np.full(3, noise_force), noise_torque_S=np.full(3, noise_torque), mount_rotation_SE=mount
        ),
        motion=RandomTour(seed=seed, segment_s=1.0, max_translation=0.05),
        seed=seed,
        inertia=False,
    )


def quantise(path, step_force: float, step_torque: float, add=None) -> None:
    """Round every wrench column of a CSV to its ADC step (N, N·m), after adding ``add`` {column: (n,)} if given."""
    for axis in AXES:
        step = step_force if axis[0] == "f" else step_torque
        extra = (add or {}).get(axis, 0.0)
        _set_column(path, axis, lambda x, step=step, extra=extra: np.round((x + extra) / step) * step)


@pytest.mark.parametrize(
    ("seed", "noise_force", "noise_torque"), [(301, 0.003, 0.0002), (302, 0.002, 0.0001), (303, 0.001, 0.00005)]
)
def test_a_quiet_sensor_with_coarse_steps_raises_no_alarm(tmp_path, seed, noise_force, noise_torque):
    """A 16-bit-like sensor, 0.01 N and 0.5 mN·m steps, whose noise is 0.1-0.4 of a step: its sample-to-sample
    differences are mostly zero, and their MAD read the noise 1.1-1.3x low on the channels that sweep many levels
    and 4-12x low on tz, which hardly moves on this tour. The report flagged a leftover on five or six channels
    (tz at 4.2-12.5x its noise), called every file saturated (a quantised peak holds its level for a few rows)
    and, on two, the final RMS above 1.5x the noise. With the quantiser's own variance in the noise figure each
    channel's figure is within 3 % of the RMS the true model leaves (0.99-1.02x), and nothing is flagged, named
    or called saturated."""
    world = quiet_world(seed, noise_force, noise_torque)
    path = tmp_path / f"quiet_{seed}.csv"
    write_csv(world, path, 30.0, 250.0)
    quantise(path, 0.01, 0.0005)
    rows = np.loadtxt(path, delimiter=",", skiprows=1)
    truth = world.wrench(rows[:, 0], noise=False)
    true_rms = np.sqrt(np.mean((rows[:, 1:7] - np.c_[truth["force_S"], truth["torque_S"]]) ** 2, axis=0))
    result = discrepancy(path)
    assert result["effects"] == [] and result["gated"] == 0
    assert not any(result["warnings"].values()), (result["warnings"], result["notes"])
    assert [c["step"] for c in result["data_quality"]["channels"].values()] == pytest.approx([0.01] * 3 + [5e-4] * 3)
    noise = np.r_[result["axis_noise"]["force_S"], result["axis_noise"]["torque_S"]]
    np.testing.assert_allclose(noise / true_rms, 1.0, atol=0.03)
    over = np.r_[
        result["leftover"]["rms_over_axis_noise"]["force_S"], result["leftover"]["rms_over_axis_noise"]["torque_S"]
    ]
    assert over.max() < result["leftover"]["threshold"]


def test_the_quantised_noise_figure_is_what_the_rounding_leaves_at_any_noise():
    """From a noise of a twentieth of a step to two steps, on every channel (the torques' tz hardly moves, the
    forces sweep many levels a second): the figure from the residual's differences against the RMS the true
    model leaves, within 3 %; the plain MAD of the differences reads the slow tz up to 13x low, and 1.5x high at
    half a step."""
    seed, step = 304, np.array([0.01] * 3 + [5e-4] * 3)
    t = np.arange(7500) / 250.0
    for ratio in (0.05, 0.2, 0.5, 1.0, 2.0):
        world = quiet_world(seed, ratio * 0.01, ratio * 5e-4)
        reading, truth = world.wrench(t), world.wrench(t, noise=False)
        y = np.round(np.c_[reading["force_S"], reading["torque_S"]] / step) * step
        predicted = np.c_[truth["force_S"], truth["torque_S"]]
        residual = y - predicted
        true_rms = np.sqrt(np.mean(residual**2, axis=0))
        np.testing.assert_allclose(axis_noise(residual, step, predicted) / true_rms, 1.0, atol=0.03, err_msg=str(ratio))
        np.testing.assert_array_equal(axis_noise(residual), axis_noise(residual, np.full(6, np.nan), predicted))


def test_a_quantised_quiet_sensor_still_shows_what_is_missing(tmp_path):
    """The floor is the rounding's, not a blanket: on the quiet sensor (0.003 N against a 0.01 N step) a 1.5°
    mount rotation is named, and a swing of one step (0.01 N at 0.2 Hz, a cable) on fz alone is flagged on fz
    (at ~2x its noise) and nowhere else, with nothing named."""
    world = quiet_world(305, 0.003, 0.0002, mount=np.deg2rad([1.0, -1.0, 0.5]))
    path = tmp_path / "quiet_mount.csv"
    write_csv(world, path, 30.0, 250.0)
    quantise(path, 0.01, 0.0005)
    result = discrepancy(path)
    assert result["effects"] == ["mount_rotation"] and not result["warnings"]["leftover"], result["notes"]
    world = quiet_world(305, 0.003, 0.0002)
    write_csv(world, path, 30.0, 250.0)
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0)
    quantise(path, 0.01, 0.0005, add={"fz": 0.01 * np.sin(2 * np.pi * 0.2 * t)})
    result = discrepancy(path)
    assert result["effects"] == [] and result["leftover"]["axes"] == ["fz"], result["leftover"]
    assert result["leftover"]["rms_over_axis_noise"]["force_S"][2] > 1.5
    assert abs(result["leftover"]["where"]["fz"]["peak_hz"] - 0.2) <= 1 / 30.0


def test_a_saturating_channel_is_flagged_with_where_and_how_much(tmp_path):
    """fz clipped at its 93rd percentile (a sensor at the end of its range on 7 % of the rows): the clipped rows
    read the range, not the force. The report flags fz and only fz, with the level, the share and the time span,
    and a note; the same recording unclipped flags nothing, and neither do the real recordings (test above)."""
    world = SimWorld(motion=RandomTour(seed=41, segment_s=1.0, max_translation=0.05), seed=41, inertia=False)
    path = tmp_path / "clip.csv"
    write_csv(world, path, 30.0, 250.0)
    clean = discrepancy(path)
    assert not clean["warnings"]["saturated"] and clean["data_quality"]["saturated"] == []
    assert all(c["pinned_share"] == 0.0 for c in clean["data_quality"]["channels"].values())
    limit = {}
    clipped = _set_column(path, "fz", lambda x: np.minimum(x, limit.setdefault("fz", float(np.quantile(x, 0.93)))))
    result = discrepancy(path)
    assert result["warnings"]["saturated"] and result["data_quality"]["saturated"] == ["fz"]
    fz = result["data_quality"]["channels"]["fz"]
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0)
    # the rows in runs of three or more at the limit: the noise dithers the force across it at each crossing
    edges = np.flatnonzero(np.diff(np.concatenate(([0], (clipped == limit["fz"]).astype(int), [0]))))
    runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= 3]
    assert fz["pinned_at"] == pytest.approx(limit["fz"], rel=1e-9)
    assert fz["pinned_share"] * result["usable"] == pytest.approx(sum(b - a for a, b in runs), abs=3)
    assert fz["pinned_from"] == pytest.approx(t[runs[0][0]]) and fz["pinned_to"] == pytest.approx(t[runs[-1][1] - 1])
    assert any(note.startswith("fz is pinned at") for note in result["notes"])


def test_a_quantised_channel_reports_its_step():
    """A 16-bit-like grid of 0.05 N under 0.12 N of noise: the step is found (to the grid's own rounding) and put
    beside the noise; values off any grid have none; a log that repeats whole rows is no clip."""
    from hapticlab.sessions.discrepancy.quality import pinned_rows, quantisation_step

    rng = np.random.default_rng(3)
    x = np.round((2.0 + rng.normal(0.0, 0.12, 5000)) / 0.05) * 0.05
    assert quantisation_step(x) == pytest.approx(0.05, rel=1e-6)
    assert quantisation_step(rng.normal(0.0, 0.12, 5000)) is None
    rows = np.repeat(rng.normal(size=(40, 6)), 5, axis=0)  # 40 poses, 5 identical rows each (the LWR4 logs)
    assert not pinned_rows(rows[:, 2], np.delete(rows, 2, axis=1)).any()
    clip = rows.copy()
    clip[:, 2] = np.minimum(clip[:, 2] + rng.normal(0, 0.01, len(clip)), 0.5)
    clip[:, [0, 1]] += rng.normal(0, 0.01, (len(clip), 2))  # the other channels still move
    assert pinned_rows(clip[:, 2], np.delete(clip, 2, axis=1)).sum() >= 5


def coloured_recording(tmp_path, seed: int, rho: float, mount: bool = False, swing: float = 0.0):
    """The tour with the sensor's noise low-passed: AR(1) of coefficient ``rho`` (a first-order filter at
    −ln(ρ)·250/2π Hz), 0.12 N and 0.01 N·m per axis in all, seeded; optionally a 2.7° mount, and a 0.2 Hz swing of
    ``swing`` N on fz (a cable)."""
    sensor = SensorParams(
        noise_force_S=np.zeros(3),
        noise_torque_S=np.zeros(3),
        mount_rotation_SE=np.deg2rad([2.0, -1.5, 1.0]) if mount else np.zeros(3),
    )
    motion = RandomTour(seed=seed, segment_s=1.0, max_translation=0.05)
    world = SimWorld(sensor=sensor, motion=motion, seed=seed, inertia=False)
    path = tmp_path / f"coloured_{seed}.csv"
    write_csv(world, path, 30.0, 250.0)
    t = np.loadtxt(path, delimiter=",", skiprows=1, usecols=0)
    rng = np.random.default_rng(seed)
    innovation = rng.normal(size=(len(t), 6)) * np.sqrt(1 - rho**2)
    noise = np.zeros_like(innovation)
    noise[0] = rng.normal(size=6)
    for i in range(1, len(t)):
        noise[i] = rho * noise[i - 1] + innovation[i]
    for k, axis in enumerate(AXES):
        scale = 0.12 if axis[0] == "f" else 0.01
        extra = swing * np.sin(2 * np.pi * 0.2 * t) if axis == "fz" else 0.0
        _set_column(path, axis, lambda x, k=k, scale=scale, extra=extra: x + scale * noise[:, k] + extra)
    return path


@pytest.mark.parametrize(("seed", "rho"), [(331, 0.6), (332, 0.9)])
def test_a_coloured_noise_is_noise(tmp_path, seed, rho):
    """A low-passed sensor noise (ρ = 0.6, 0.9): sample-to-sample differences see √(1 − ρ) of it, so every
    channel read 1.54-1.65x (ρ = 0.6) and 3.05-3.2x (ρ = 0.9) its noise and both warnings fired on a clean file.
    Over the lag where the noise decorrelates the figure is within 5 % of the 0.12 N it is, and nothing fires."""
    result = discrepancy(coloured_recording(tmp_path, seed, rho))
    assert result["effects"] == [] and not any(result["warnings"].values()), result["notes"]
    np.testing.assert_allclose(result["axis_noise"]["force_S"], 0.12, rtol=0.05)
    np.testing.assert_allclose(result["axis_noise"]["torque_S"], 0.01, rtol=0.05)
    assert result["leftover"]["independent_samples"] < (1 - rho) / (1 + rho) * result["usable"] * 1.3


@pytest.mark.parametrize(("seed", "rho"), [(336, 0.6), (337, 0.8)])
def test_a_mount_under_a_coloured_noise_is_named(tmp_path, seed, rho):
    """A 2.7° mount under a low-passed noise: it gained 9 % on held-out data and was named, then set aside by
    the structure test (it explained 24 % of a "structure" that was the noise's colour), leaving nothing named
    and every channel flagged at 1.6-2.7x. Now it is named (structure 100 %) and nothing is flagged."""
    result = discrepancy(coloured_recording(tmp_path, seed, rho, mount=True))
    assert result["effects"] == ["mount_rotation"] and not any(result["warnings"].values()), result["steps"]
    np.testing.assert_allclose(
        result["final"]["params"]["mount_rotation"]["mount_rotation_SE"], np.deg2rad([2.0, -1.5, 1.0]), atol=0.003
    )


def test_a_leftover_under_a_coloured_noise_is_still_flagged(tmp_path):
    """A 0.1 N, 0.2 Hz swing on fz under a noise of ρ = 0.6: flagged on fz alone (1.15x against a threshold of
    1.10x, for the ~1 800 independent samples the 7 500 are worth), nothing named."""
    result = discrepancy(coloured_recording(tmp_path, 335, 0.6, swing=0.1))
    assert result["effects"] == [] and result["leftover"]["axes"] == ["fz"]
    assert abs(result["leftover"]["where"]["fz"]["peak_hz"] - 0.2) <= 1 / 30.0
