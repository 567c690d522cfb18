"""UR arm geometry: the published DH table, forward kinematics and the 8 closed-form IK solutions."""

from __future__ import annotations

import numpy as np
import pytest

from hapticlab.plugins.kinematics.ur_arm import CB3_MODELS, HOME_Q, UR_DH, URArm, forward, inverse, inverse_nearest


def wrapped(angle):
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def test_the_table_is_a_plain_constant_of_six_joints_per_model():
    assert {"ur3e", "ur5e", "ur10e", "ur16e", "ur5"} <= set(UR_DH)
    for model, dh in UR_DH.items():
        assert dh.a.shape == dh.d.shape == dh.alpha.shape == (6,), model
        np.testing.assert_array_equal(dh.alpha, [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0])
    assert UR_DH["ur5e"].d[0] == 0.1625 and UR_DH["ur5e"].a[2] == -0.3922  # UR's published numbers
    assert CB3_MODELS < set(UR_DH)
    with pytest.raises(ValueError, match="read-only"):
        UR_DH["ur5e"].a[0] = 1.0  # read-only: nobody edits the shared table by accident


@pytest.mark.parametrize("model", sorted(UR_DH))
def test_zero_configuration_is_the_arm_stretched_out_along_minus_x(model):
    """At q = 0 a UR lies straight along −x of Base: flange at (a2 + a3, −(d4 + d6), d1 − d5), z_E along −y."""
    dh = UR_DH[model]
    R_BE, p_BoEo_B = forward(dh, np.zeros(6))
    np.testing.assert_allclose(p_BoEo_B, [dh.a[1] + dh.a[2], -(dh.d[3] + dh.d[5]), dh.d[0] - dh.d[4]], atol=1e-15)
    np.testing.assert_allclose(R_BE, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)  # Rx(π/2)


def test_home_configuration_points_the_flange_down():
    R_BE, _ = URArm("ur5e").forward(HOME_Q)
    np.testing.assert_allclose(R_BE[:, 2], [0, 0, -1], atol=1e-15)


@pytest.mark.parametrize("model", sorted(UR_DH))
def test_every_ik_solution_reproduces_the_pose_to_1e_9(model):
    """FK(IK(pose)) == pose for 300 random reachable poses; the original q is among the solutions."""
    arm = URArm(model)
    rng = np.random.default_rng(13)
    counts = []
    for _ in range(300):
        q = rng.uniform(-np.pi, np.pi, 6)
        R_BE, p_BoEo_B = arm.forward(q)
        solutions = arm.inverse(R_BE, p_BoEo_B)
        counts.append(len(solutions))
        assert len(solutions) >= 1
        for s in solutions:
            R, p = arm.forward(s)
            np.testing.assert_allclose(R, R_BE, atol=1e-9)
            np.testing.assert_allclose(p, p_BoEo_B, atol=1e-9)
        distance = np.sort(np.abs(wrapped(solutions - q)).max(axis=1))
        assert distance[0] < 1e-7
        if len(distance) == 1 or distance[1] > 0.1:  # away from where two branches meet
            nearest = arm.inverse_nearest(R_BE, p_BoEo_B, q_near=q + rng.normal(0, 0.01, 6))
            np.testing.assert_allclose(nearest, q, atol=1e-7)
    assert max(counts) == 8  # all 8 branches appear where the pose allows them


def test_nearest_branch_is_continuous_along_a_path_and_unwraps_past_pi():
    """Follow a joint path that turns joint 6 through 3π: IK of each FK pose gives the path back."""
    arm = URArm("ur5e")
    t = np.linspace(0.0, 1.0, 400)
    path = HOME_Q + np.column_stack(
        [0.5 * np.sin(2 * np.pi * t), 0.3 * t, -0.4 * t, 0.6 * t, 0.2 * np.sin(np.pi * t), 3 * np.pi * t]
    )
    q = path[0]
    for q_true in path:
        q = arm.inverse_nearest(*arm.forward(q_true), q_near=q)
        np.testing.assert_allclose(q, q_true, atol=1e-7)
    assert q[5] > 2 * np.pi  # not wrapped back into [−π, π)


def test_out_of_reach_has_no_solution():
    arm = URArm("ur3e")
    R_BE = np.diag([1.0, -1.0, -1.0])
    assert len(arm.inverse(R_BE, np.array([2.0, 0.0, 0.3]))) == 0
    assert arm.inverse_nearest(R_BE, np.array([2.0, 0.0, 0.3])) is None
    assert len(inverse(UR_DH["ur3e"], R_BE, np.zeros(3))) == 0  # on the base axis: inside the shoulder offset


def test_wrist_singularity_keeps_the_previous_q6():
    """sin θ5 = 0: θ6 and θ2+θ3+θ4 trade off; the nearest solution keeps θ6 and still reproduces the pose."""
    arm = URArm("ur5e")
    q = np.array([0.3, -1.2, 1.4, -0.5, 0.0, 0.7])
    R_BE, p = arm.forward(q)
    q_back = inverse_nearest(arm.dh, R_BE, p, q_near=q)
    R, p_back = arm.forward(q_back)
    np.testing.assert_allclose(R, R_BE, atol=1e-9)
    np.testing.assert_allclose(p_back, p, atol=1e-9)
    assert q_back[5] == pytest.approx(0.7)


def test_unknown_model_names_the_known_ones():
    with pytest.raises(ValueError, match=r"model: must be 'ur3e', 'ur5e', .* or 'ur10', got 'ur7e'"):
        URArm("ur7e")
