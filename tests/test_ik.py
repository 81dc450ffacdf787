"""Public inverse kinematics on the full model (issue 10, item 1)."""

from __future__ import annotations

import numpy as np
from conftest import random_parameters

import fgcal
from fgcal.core.se3 import so3_log

RNG = np.random.default_rng(10)


def _calibrated():
    """A KR 125/2 with every kind of deviation, compliances included, and a 100 kg payload."""
    robot = fgcal.load_robot("kuka_kr125_2")
    robot = robot.with_tool(robot.tool_pose, payload_mass=100.0, payload_com=[0.0, 0.0, 0.2])
    return robot, random_parameters(robot, RNG)


def _random_q(robot, n: int) -> np.ndarray:
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    return RNG.uniform(0.8 * low, 0.8 * high, (n, robot.n_joints))


def test_pose_targets_are_reached_on_the_full_model():
    robot, params = _calibrated()
    q_true = _random_q(robot, 40)
    tcp = np.array([0.01, -0.02, 0.25])
    T = robot.fk_tool(q_true, params)
    T[:, :3, 3] += T[:, :3, :3] @ tcp
    result = robot.ik(T, q_true + RNG.normal(0, 0.05, q_true.shape), params, tcp=tcp)
    ok = result.status != "unreachable"
    assert ok.mean() > 0.95, result.status
    assert np.all(result.residual_m[ok] < 1e-9) and np.all(result.residual_rad[ok] < 1e-9)
    # On the hint's branch: the true joints, not another solution.
    assert np.allclose(result.q[ok], q_true[ok], atol=1e-6)


def test_position_targets_take_the_smallest_joint_change_from_the_hint():
    robot, params = _calibrated()
    q_start = _random_q(robot, 30)
    p_start = robot.fk_tool(q_start, params)[:, :3, 3]
    targets = p_start + RNG.normal(0, 0.01, p_start.shape)  # a centimetre away
    result = robot.ik(targets, q_start, params)
    assert np.all(result.residual_m < 1e-9)
    # Any other solution reached from a nearby start is at least as far from the hint.
    other = robot.ik(targets, q_start + RNG.normal(0, 0.02, q_start.shape), params)
    change = np.linalg.norm(result.q - q_start, axis=1)
    other_change = np.linalg.norm(other.q - q_start, axis=1)
    assert np.all(change <= other_change + 1e-6)
    assert np.all(change < 0.1)  # a centimetre needs a small joint change, not another branch


def test_unreachable_outside_limits_and_singular_targets_are_said():
    robot, params = _calibrated()
    q = _random_q(robot, 3)
    far = robot.fk_tool(q, params)[:, :3, 3] + np.array([20.0, 0.0, 0.0])
    assert list(robot.ik(far, q, params).status) == ["unreachable"] * 3
    # Reachable only with joint 2 beyond its limit.
    q_out = q[:1].copy()
    q_out[0, 1] = robot.limits[1, 1] + 0.3  # joint 2: no turn of 2 pi brings it back
    target = robot.fk_tool(q_out, params)
    assert robot.ik(target, q_out, params).status[0] == "outside joint limits"
    # The nominal wrist straight (q5 = 0): axes 4 and 6 align. (With the random distortions
    # above they would not, quite.)
    q_singular = q[:1].copy()
    q_singular[0, 4] = 0.0
    target = robot.fk_tool(q_singular)
    result = robot.ik(target, q_singular + 1e-3)
    assert result.status[0] == "near singularity", (result.status, result.residual_m)


def test_a_single_target_and_the_nominal_model():
    robot = fgcal.load_robot("abb_irb120")
    q = np.array([0.1, -0.3, 0.2, 0.4, 0.5, -0.6])
    T = robot.fk_tool(q)
    result = robot.ik(T, q + 0.02)
    assert result.q.shape == (1, 6) and result.status[0] == "ok"
    back = robot.fk_tool(result.q[0])
    assert np.linalg.norm(so3_log(back[:3, :3].T @ T[:3, :3])) < 1e-9
    assert np.linalg.norm(back[:3, 3] - T[:3, 3]) < 1e-9


def test_bad_targets_and_hints_are_clear_errors():
    import pytest

    robot = fgcal.load_robot("abb_irb120")
    q = np.zeros(6)
    with pytest.raises(fgcal.InputError, match="targets"):
        robot.ik(np.array([0.3, np.nan, 0.4]), q)
    with pytest.raises(fgcal.InputError, match="targets"):
        robot.ik(np.zeros((2, 2)), np.zeros((2, 6)))
    with pytest.raises(fgcal.InputError, match="q_hint"):
        robot.ik(np.zeros((2, 3)), np.zeros((3, 6)))
    with pytest.raises(fgcal.InputError, match="6 joints"):
        robot.ik(np.zeros(3), np.zeros(5))


def test_the_simulators_ik_stops_later_starts_without_changing_the_first_converged():
    """solve_ik's target_of: a target's starts after its first converged one stop; that first
    one, and every start before it, end exactly as when every start runs to the end."""
    from fgcal.simulation.ik import solve_ik

    robot, values = _calibrated()
    params = robot.parameter_vector(values)
    starts = 6
    T = np.repeat(robot.fk(_random_q(robot, 30), values), starts, axis=0)
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q0 = RNG.uniform(np.maximum(low, -np.pi), np.minimum(high, np.pi), (len(T), robot.n_joints))
    q_all, ok_all = solve_ik(robot, params, T, q0, freeze_converged=True)
    target_of = np.arange(len(T)) // starts
    q_first, ok_first = solve_ik(robot, params, T, q0, freeze_converged=True, target_of=target_of)
    assert ok_all.any() and not ok_all.all()  # some targets' first start fails: later ones matter
    for target in range(len(T) // starts):
        rows = np.arange(target * starts, (target + 1) * starts)
        converged = rows[ok_all[rows]]
        if not len(converged):
            assert not ok_first[rows].any()
            continue
        first = converged[0]
        assert ok_first[first] and not ok_first[rows[rows < first]].any()
        assert np.array_equal(q_first[rows[rows <= first]], q_all[rows[rows <= first]])
    assert ok_first.sum() < ok_all.sum()  # later starts did stop
