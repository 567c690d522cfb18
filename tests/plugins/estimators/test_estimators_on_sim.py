"""The estimators on data from the simulated world's physics (not from the model they fit)."""

from __future__ import annotations

import numpy as np

from hapticlab.core.types import AlignedSamples
from hapticlab.plugins.estimators.batch import BatchEstimator
from hapticlab.plugins.estimators.rls import RLSEstimator
from hapticlab.plugins.simworld import SimWorld


def world_block(table: dict, seconds: float, rate_hz: float = 1000.0):
    world = SimWorld.from_config(table)
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    w = world.wrench(t)
    n = len(t)
    block = AlignedSamples(
        t_ns=np.round(t * 1e9).astype(np.int64),
        force_S=w["force_S"],
        torque_S=w["torque_S"],
        R_EB=w["R_EB"],
        seq=np.arange(n),
        status=w["status"],
        stale=np.zeros(n, dtype=bool),
    )
    return block, w, world.truth()


def test_rls_recovers_the_simulated_tool_and_sensor():
    # the paper's identification: random orientations, no contact, ATI Gamma-class noise,
    # CoG 4.35 cm along the sensor z axis; quasi-static (inertia off) as the model assumes
    block, _, truth = world_block({"seed": 3, "inertia": False, "motion": {"script": "random_tour"}}, 20.0)
    est = RLSEstimator()
    out = est.update_block(block)
    p = est.params()
    assert np.abs(np.subtract(p["gravity_force_B"], truth["gravity_force_B"])).max() < 0.02  # N
    assert np.abs(np.subtract(p["bias_force_S"], truth["bias_force_S"])).max() < 0.02  # N
    assert np.abs(np.subtract(p["cog_S"], truth["cog_S"])).max() < 0.001  # m
    assert np.abs(np.subtract(p["bias_torque_S"], truth["bias_torque_S"])).max() < 0.001  # N·m
    assert not out.contact.any()
    # after convergence only the sensor noise (0.12 N per axis) is left
    after = out.contact_force_S[est.first_converged_force + 1000 :]
    assert np.all(np.sqrt(np.mean(after**2, axis=0)) < 0.12 * 1.05)


def test_rls_reports_the_indentation_and_batch_absorbs_it():
    table = {
        "seed": 4,
        "inertia": False,
        "motion": {"script": "random_tour"},
        "contacts": [{"kind": "indentation", "start": 12.0, "duration": 4.0, "peak_force": 3.0, "ramp": 0.3}],
    }
    block, w, _ = world_block(table, 20.0)
    pressing = w["contact"] & (np.linalg.norm(w["contact_force_S"], axis=1) > 2.9)
    rls = RLSEstimator().update_block(block)
    err_rls = np.linalg.norm(rls.contact_force_S[pressing] - w["contact_force_S"][pressing], axis=1)
    assert rls.contact[pressing].all() and err_rls.mean() < 0.25
    batch = BatchEstimator().update_block(block)
    err_batch = np.linalg.norm(batch.contact_force_S[pressing] - w["contact_force_S"][pressing], axis=1)
    # the batch baseline has no gate: contact leaks into its parameters
    assert err_batch.mean() > 2 * err_rls.mean()
