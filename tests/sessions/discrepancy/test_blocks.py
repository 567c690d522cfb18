"""The workflow's passes by blocks of rows give the whole-array numbers (``sessions/discrepancy/blocks.py``), and
each candidate's Jacobian columns from the model with that candidate alone are the full model's (``heldout``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hapticlab.core.estimation.batch import batch_fit
from hapticlab.core.host.registry import Registry
from hapticlab.core.parallel import workers
from hapticlab.core.sensor_model import Model
from hapticlab.plugins.simworld import RandomTour, RobotParams, SensorParams, SimWorld
from hapticlab.plugins.simworld.export import write_csv
from hapticlab.sessions.discrepancy import blocks
from hapticlab.sessions.discrepancy.blocks import batch_fit_rows, predict_rows, weight_rows
from hapticlab.sessions.discrepancy.heldout import candidate_jacobian
from hapticlab.sessions.discrepancy.identify import Identification
from hapticlab.sessions.discrepancy.report import json_ready
from hapticlab.sessions.discrepancy.skew import ClockSkew
from hapticlab.sessions.discrepancy.workflow import discrepancy
from hapticlab.sessions.recording import load_stream


@pytest.fixture(scope="module")
def fit(tmp_path_factory) -> Identification:
    """6 s at 500 Hz of a lively tour with translations (3000 rows), a mount rotation and a 8 ms lag."""
    world = SimWorld(
        sensor=SensorParams(mount_rotation_SE=np.deg2rad([2.0, -1.5, 1.0])),
        robot=RobotParams(kinematics_lag_s=0.008),
        motion=RandomTour(seed=7, segment_s=1.0, max_translation=0.05),
        seed=7,
        inertia=True,
    )
    path = tmp_path_factory.mktemp("blocks") / "tour.csv"
    write_csv(world, path, 6.0, 500.0)
    return Identification(load_stream(path))


def effect(name: str):
    return ClockSkew() if name == "clock_skew" else Registry().create("effect", name, {}, where=name)


BASE = np.array([1.0, 2.0, -3.4, 0.1, 0.2, 0.3, 0.001, 0.002, 0.05, 0.01, 0.02, 0.03])

CASES = {
    "base": ([], {}),
    "row by row": (
        ["inertia", "mount_rotation", "bias_drift", "gain_crosstalk"],
        {"mount_rotation": [0.03, -0.02, 0.01]},
    ),
    "lag": (["inertia", "time_lag"], {"time_lag": [0.008]}),
    "long negative lag": (["time_lag"], {"time_lag": [-0.3]}),
    "skew": (["clock_skew", "payload_change"], {"clock_skew": [0.004, 3e-4], "payload_change": [0.02, 0, 0, 0.01]}),
    "lag and skew": (["time_lag", "clock_skew"], {"time_lag": [0.006], "clock_skew": [-0.002, -2e-4]}),
    "hysteresis (whole arrays)": (["hysteresis"], {"hysteresis": [0.01] * 6}),
}


@pytest.mark.parametrize("case", CASES)
def test_a_prediction_by_blocks_is_the_whole_arrays_one_bit_for_bit(fit, case):
    names, params = CASES[case]
    effects = [(name, effect(name)) for name in names]
    for name, e in effects:
        assert e.check(fit.motion) is None, name
    model = Model(effects)
    theta = model.initial(BASE)
    if "inertia" in names:
        theta[model.slices["inertia"].start] = 1.0
    for name, value in params.items():
        theta[model.slices[name]] = value
    whole, weight = model.predict6(fit.motion, theta), model.weight_S(fit.motion, theta)
    for block in (257, 1000, 4096):  # blocks that cut the recording anywhere, and one block
        with workers(2):  # the blocks side by side, whatever this machine's cores
            assert np.array_equal(predict_rows(Model(effects), fit.motion, theta, block), whole), block
            assert np.array_equal(weight_rows(Model(effects), fit.motion, theta, block), weight), block


def test_the_batch_fit_by_blocks_is_lstsq_on_the_stacked_rows(fit):
    force_S, torque_S, R_EB = fit.y[:, :3], fit.y[:, 3:], fit.motion.R_EB
    rows = fit.usable.copy()
    rows[::7] = False  # not every row, as the gate leaves them
    whole = batch_fit(force_S[rows], torque_S[rows], R_EB[rows])
    one_block = batch_fit_rows(force_S, torque_S, R_EB, rows)
    for key, value in whole.items():
        assert np.array_equal(one_block[key], value), key  # at most one block: batch_fit itself
    blocks = batch_fit_rows(force_S, torque_S, R_EB, rows, block=500)
    for key, value in whole.items():
        assert np.allclose(blocks[key], value, rtol=1e-9, atol=1e-12), key


def test_each_candidates_jacobian_columns_are_the_full_models(fit):
    candidates = [(name, effect(name)) for name in ("bias_drift", "gain_crosstalk", "mount_rotation", "time_lag")]
    model = Model([("inertia", effect("inertia"))])
    theta = model.initial(BASE)
    theta[12] = 1.0
    full = Model(model.effects + candidates)
    theta_full = full.initial(BASE)
    theta_full[: model.size] = theta
    J = candidate_jacobian(model, candidates, full, fit.fit_motion, theta_full)
    assert np.array_equal(J, full.jacobian(fit.fit_motion, theta_full))


def test_the_result_does_not_depend_on_how_the_rows_are_laid_out(fit):
    """A reader may hand over columns of one wide table (strided views) instead of arrays of their own."""
    stream = fit.stream
    samples = stream.samples
    parts = [stream.t_s[:, None], samples.force_S, samples.torque_S, samples.quat_BE, samples.p_BoEo_B]
    table = np.asfortranarray(np.concatenate(parts, axis=1))  # column by column, as a columnar reader
    rows = np.concatenate(parts, axis=1)  # row by row, as a row reader
    results = []
    for wide in (table, rows):
        laid_out = dataclasses.replace(
            samples, force_S=wide[:, 1:4], torque_S=wide[:, 4:7], quat_BE=wide[:, 7:11], p_BoEo_B=wide[:, 11:14]
        )
        results.append(json_ready(discrepancy(dataclasses.replace(stream, t_s=wide[:, 0], samples=laid_out))))
    assert results[0] == results[1] == json_ready(discrepancy(stream))


def test_threads_change_no_number_of_a_jacobian_nor_the_mass_an_effect_notes(fit):
    """The Jacobian's columns are predicted in threads (``core/parallel.py``); ``payload_change`` notes the
    tool's mass from its last prediction for ``describe``: the mass at theta, as in order."""
    names = ["inertia", "mount_rotation", "time_lag", "payload_change"]
    theta = Model([(name, effect(name)) for name in names]).initial(BASE)
    results = []
    for count in (1, 2):
        effects = [(name, effect(name)) for name in names]
        for _, e in effects:
            assert e.check(fit.motion) is None
        model = Model(effects)
        with workers(count):
            J = model.jacobian(fit.fit_motion, theta)
        results.append((J, dict(effects)["payload_change"].mass_kg))
    assert np.array_equal(results[0][0], results[1][0])
    assert results[0][1] == results[1][1] == pytest.approx(np.linalg.norm(BASE[:3]) / 9.80665, rel=1e-12)


def test_the_workflow_gives_the_same_result_on_one_thread_and_on_two(fit, monkeypatch):
    monkeypatch.setattr(blocks, "BLOCK_ROWS", 500)  # its passes over every row go by blocks too
    with workers(1):
        one = json_ready(discrepancy(fit.stream))
    with workers(2):
        two = json_ready(discrepancy(fit.stream))
    assert one == two
