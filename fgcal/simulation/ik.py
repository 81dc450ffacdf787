"""Batched numerical inverse kinematics (damped least squares on the analytic Jacobian)."""

from __future__ import annotations

import numpy as np

from ..core.se3 import so3_log
from ..model import kinematics
from ..model.ik import wrap_into_limits
from ..model.robot import Robot


def pose_error(T: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """Body-frame error (N, 6) ``[rotvec, R^T dp]`` from poses T to T_target."""
    R_t = np.swapaxes(T[:, :3, :3], 1, 2)
    rot = so3_log(R_t @ T_target[:, :3, :3])
    trans = (R_t @ (T_target[:, :3, 3] - T[:, :3, 3])[..., None])[..., 0]
    return np.concatenate([rot, trans], axis=1)


def solve_ik(
    robot: Robot,
    params: np.ndarray,
    T_target: np.ndarray,
    q0: np.ndarray,
    frame: str = "flange",
    iterations: int = 80,
    tol: float = 1e-9,
    freeze_converged: bool = False,
    target_of: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles (N, n) reaching ``T_target`` (N, 4, 4) from starts ``q0``.

    Returns (q, converged) where converged means rotation and translation errors below
    ``tol`` (rad, m) and all joints within limits (after wrapping by 2 pi where possible).
    ``freeze_converged``: stop iterating each problem once it is within ``tol`` (faster; the
    default iterates all to the end, as the simulator did before: its configurations then move
    by up to 3e-9 rad). ``target_of`` (N,), with ``freeze_converged``: the rows are starts of
    these targets, each target's in order of preference, and only the first converged start of
    a target is used: once a start is converged within the limits, its target's later starts
    stop iterating (those that converged by then still say so).
    """
    if target_of is not None and not freeze_converged:
        raise ValueError("target_of stops starts once converged: it needs freeze_converged")
    joints = [f"q{i}" for i in range(1, robot.n_joints + 1)]
    q = q0.copy()
    damping = 1e-4
    active = np.arange(len(q))
    revolute = ~robot.prismatic
    stops_later_starts = target_of is not None and len(q) > 0
    if stops_later_starts:
        target_of = np.unique(target_of, return_inverse=True)[1]
        first_settled = np.full(target_of.max() + 1, len(q))  # row of each target's first converged start
    for _ in range(iterations):
        data = kinematics.forward(robot, params, q[active])
        err = pose_error(kinematics.frame_pose(robot, data, frame), T_target[active])
        if freeze_converged:
            moving = (np.linalg.norm(err[:, :3], axis=1) >= tol) | (np.linalg.norm(err[:, 3:], axis=1) >= tol)
            if stops_later_starts:
                settled = active[~moving]
                settled = settled[_within(robot, q[settled])]
                np.minimum.at(first_settled, target_of[settled], settled)
                moving &= active < first_settled[target_of[active]]
            if not np.any(moving):
                break
        J = kinematics.jacobian(robot, data, joints, frame=frame)
        if freeze_converged and not np.all(moving):
            # Rows are independent: dropping the converged ones from J costs less than
            # copying the chain's frames of the others (KinematicsData.subset).
            active, err, J = active[moving], err[moving], J[moving]
        JtJ = np.swapaxes(J, 1, 2) @ J + damping * np.eye(robot.n_joints)
        step = np.linalg.solve(JtJ, (np.swapaxes(J, 1, 2) @ err[..., None]))[..., 0]
        # Limit the step so that far starts do not jump across the workspace.
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        q_new = q[active] + step * np.minimum(1.0, 0.5 / np.maximum(norm, 1e-12))
        q[active] = np.where(revolute, np.arctan2(np.sin(q_new), np.cos(q_new)), q_new)
    data = kinematics.forward(robot, params, q)
    err = pose_error(kinematics.frame_pose(robot, data, frame), T_target)
    converged = (np.linalg.norm(err[:, :3], axis=1) < tol) & (np.linalg.norm(err[:, 3:], axis=1) < tol)
    return wrap_into_limits(robot.limits, q, robot.prismatic), converged & _within(robot, q)


def _within(robot: Robot, q: np.ndarray) -> np.ndarray:
    """(N,) whether each configuration is within the joint limits once wrapped by 2 pi."""
    wrapped = wrap_into_limits(robot.limits, q, robot.prismatic)
    return np.all((wrapped >= robot.limits[:, 0]) & (wrapped <= robot.limits[:, 1]), axis=1)
