"""The closed-form IK of a 6-axis arm with a spherical wrist (fgcal.model.wrist_ik), and the
controller's joints of program filtering found on the branch a target's configuration names."""

import numpy as np
import pytest

import fgcal
from fgcal.data.program_filter import configurations, controller_ik
from fgcal.model.wrist_ik import branches, wrist_arm


def _configurations(robot, n: int, seed: int) -> np.ndarray:
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    return low + (high - low) * np.random.default_rng(seed).random((n, robot.n_joints))


@pytest.mark.parametrize("name", ["kuka_kr125_2", "abb_irb120", "puma560"])
def test_every_branch_closes_and_one_is_the_configuration(name):
    robot = fgcal.load_robot(name)
    arm = wrist_arm(robot)
    assert arm is not None
    q = _configurations(robot, 300, seed=3)
    T = robot.fk(q)
    found = branches(arm, T)  # (N, 8, 6)
    exists = np.all(np.isfinite(found), axis=2)
    assert exists[:, :4].all()  # joint 1 in front or behind, two elbows: every pose within reach has them
    for k in range(8):
        rows = np.flatnonzero(exists[:, k])
        reached = robot.fk(found[rows, k])
        assert np.abs(reached[:, :3, 3] - T[rows, :3, 3]).max() < 1e-9
        assert np.abs(reached[:, :3, :3] - T[rows, :3, :3]).max() < 1e-9
    turned = np.abs((found - q[:, None] + np.pi) % (2 * np.pi) - np.pi).max(axis=2)
    assert np.all(np.nanmin(turned, axis=1) < 1e-8)


def test_no_closed_form_without_a_spherical_wrist():
    assert wrist_arm(fgcal.load_robot("ur10e")) is None


@pytest.mark.parametrize(("name", "kind"), [("kuka_kr125_2", "krl"), ("abb_irb120", "rapid")])
def test_controller_joints_are_the_branch_the_configuration_names(name, kind):
    """Targets written from joints with those joints' configuration data: the controller's
    joints are those joints (an axis at its smallest turn of the sign T names, for KRL). A
    random-start search took another solution of the same S and T (a wrist centre near axis 1)."""
    robot = fgcal.load_robot(name)
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q = low + (high - low) * (0.2 + 0.6 * np.random.default_rng(0).random((400, 6)))
    margin = np.radians(1.0)  # away from a singular wrist and from each quadrant's edge
    away = (np.abs(q[:, 4]) > margin) & np.all(np.abs(q - np.round(q / (np.pi / 2)) * np.pi / 2) > margin, axis=1)
    q = q[away]
    found_q, found = controller_ik(robot, robot.fk(q), kind, configurations(robot, kind, q))
    assert found.all()
    wrapped = np.abs((found_q - q + np.pi) % (2 * np.pi) - np.pi)
    assert wrapped.max() < 1e-7
