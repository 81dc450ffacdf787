"""Inverse kinematics on the full model (distortions, gravity compliances at the robot's
payload), with the analytic joint Jacobian: what compensation runs on.

``inverse_kinematics(robot, params, targets, q_hint)`` solves N targets at once by damped
Gauss-Newton from the hints. A target is a position (3,) of the TCP or a pose (4, 4) of the TCP
frame (the frame ``frame`` moved by ``tcp`` in it). For a position the arm is redundant, and
each step also pulls the joints toward the hint in the Jacobian's null space, so that the
answer is the smallest joint change from the hint that reaches the target, on the hint's
branch. Each answer has a status:

- ``ok``: reached within the tolerance (``tol_m``, default 1 um; ``tol_rad``, 1 urad), within
  the joint limits (after shifts of 2 pi);
- ``unreachable``: the iterations ended farther than the tolerance (out of reach, or a
  hint on the wrong side of a singularity);
- ``outside joint limits``: reached, but only outside the limits;
- ``near singularity``: reached, but the Jacobian's smallest singular value is below
  ``singular_tol`` (m/rad for positions): small target changes need large joint changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.se3 import skew, so3_log
from . import kinematics

SINGULAR_TOL = 1e-3  # smallest singular value of the TCP Jacobian, m/rad
DAMPING = 1e-9  # Levenberg damping of the steps (squared singular values)
MAX_STEP_RAD = 0.5  # joint change per iteration, so that far hints do not jump across the workspace
TOL_M, TOL_RAD = 1e-6, 1e-6  # what counts as reached (1 um, 1 urad)
CONVERGED_M, CONVERGED_RAD = 1e-11, 1e-11  # where the iterations stop: far below any tolerance
POLISH = 8  # Gauss-Newton steps without the pull toward the hint, to finish a position target
STALL = 20  # iterations without a 1 % smaller error after which a target is given up (stuck)


@dataclass
class IKResult:
    q: np.ndarray  # (N, n) joint angles, rad
    status: np.ndarray  # (N,) see the module docstring
    residual_m: np.ndarray  # (N,) TCP position error left
    residual_rad: np.ndarray | None  # (N,) orientation error left, for pose targets


def _tcp_state(
    robot: kinematics.Robot, params: np.ndarray, q: np.ndarray, frame: str, tcp: np.ndarray, moving: np.ndarray
):
    """TCP poses (N, 4, 4) and body Jacobians (N, 6, n) w.r.t. the joints: a point's body
    twist is [omega, v + omega x tcp]. On a tree, the joints off the frame's path (the other
    arm's) have no column: they move it only by bending the trunk under their weight, and stay
    where they are (at the hints): ``moving`` (n,) marks the others (kinematics.path_joints)."""
    data = kinematics.forward(robot, params, q)
    T = kinematics.frame_pose(robot, data, frame).copy()
    J = kinematics.jacobian(robot, data, [f"q{i + 1}" for i in range(robot.n_joints)], frame=frame)
    T[:, :3, 3] += T[:, :3, :3] @ tcp
    J = J * moving[None, None, :]
    J[:, 3:] -= skew(tcp) @ J[:, :3]
    return T, J


def _errors(T: np.ndarray, targets: np.ndarray, pose: bool) -> np.ndarray:
    """Body-frame errors (N, 6) [rotation, translation] for poses, (N, 3) in the body frame
    for positions (so that the same body Jacobian's translation rows apply)."""
    R_t = np.swapaxes(T[:, :3, :3], 1, 2)
    if not pose:
        return np.einsum("nij,nj->ni", R_t, targets - T[:, :3, 3])
    rotation = so3_log(R_t @ targets[:, :3, :3])
    translation = np.einsum("nij,nj->ni", R_t, targets[:, :3, 3] - T[:, :3, 3])
    return np.concatenate([rotation, translation], axis=1)


def _step(A: np.ndarray, error: np.ndarray, toward_hint: np.ndarray | None) -> np.ndarray:
    """Damped Gauss-Newton steps (N, n) for Jacobians A (N, r, n) and errors (N, r), with the
    pull ``toward_hint`` (N, n) in the null space where the rows leave one (positions)."""
    At = np.swapaxes(A, 1, 2)
    # Damped pseudo-inverse: A^T (A A^T + lambda I)^-1
    pinv = At @ np.linalg.inv(A @ At + DAMPING * np.eye(A.shape[1]))
    step = np.einsum("nij,nj->ni", pinv, error)
    if toward_hint is not None and A.shape[1] < A.shape[2]:
        null = np.eye(A.shape[2]) - pinv @ A
        step += np.einsum("nij,nj->ni", null, toward_hint)
    return step


def wrap_into_limits(limits: np.ndarray, q: np.ndarray, prismatic: np.ndarray | None = None) -> np.ndarray:
    """Shift angles by multiples of 2 pi toward the joint range (joints may exceed +-pi);
    prismatic joints (mask, m) are left as they are."""
    out = q.copy()
    revolute = True if prismatic is None else ~prismatic
    for shift in (2 * np.pi, -2 * np.pi):
        moved = out + shift * revolute
        better = (out < limits[:, 0]) | (out > limits[:, 1])
        ok = (moved >= limits[:, 0]) & (moved <= limits[:, 1])
        out = np.where(better & ok, moved, out)
    return out


def inverse_kinematics(
    robot,  # fgcal.model.robot.Robot (not imported: the Robot's ik method calls this module)
    params: np.ndarray,
    targets: np.ndarray,
    q_hint: np.ndarray,
    frame: str = "tool",
    tcp: np.ndarray | None = None,
    tol_m: float = TOL_M,
    tol_rad: float = TOL_RAD,
    iterations: int = 200,
    singular_tol: float = SINGULAR_TOL,
    clamp: bool = False,
) -> IKResult:
    """Joint angles (N, n) putting the TCP on ``targets``: positions (N, 3) or poses (N, 4, 4)
    in W, starting from ``q_hint`` (N, n); see the module docstring. The iterations go on to
    CONVERGED_M (CONVERGED_RAD); ``tol_m`` and ``tol_rad`` say what counts as reached. A
    position target's iterations pull toward the hint in the null space, which leaves them a
    few nanometres off where the pull and the error balance: a few steps without the pull
    finish them (a joint change of that order). With ``clamp`` every step is cut back into
    the joint limits: the search stays among the solutions within them (a start for targets
    without a program's joints)."""
    targets = np.asarray(targets, dtype=float)
    pose = targets.ndim == 3
    q = np.array(q_hint, dtype=float, copy=True)
    hint = q.copy()
    tcp = np.zeros(3) if tcp is None else np.asarray(tcp, dtype=float)
    rows = slice(0, 6) if pose else slice(3, 6)
    moving = kinematics.path_joints(robot, frame)
    active = np.arange(len(q))  # the targets still iterating: only they are evaluated
    best = np.full(len(q), np.inf)  # each target's smallest error so far, and when it last improved
    improved_at = np.zeros(len(q), dtype=int)
    pulling = np.ones(len(q), dtype=bool)  # still pulled toward its hint (positions)
    for k in range(iterations + POLISH):
        if not len(active):
            break
        if k == iterations:
            pulling[:] = False
        T, J = _tcp_state(robot, params, q[active], frame, tcp, moving)
        error = _errors(T, targets[active], pose)
        done = np.linalg.norm(error[:, -3:], axis=1) < CONVERGED_M
        if pose:
            done &= np.linalg.norm(error[:, :3], axis=1) < CONVERGED_RAD
        size = np.linalg.norm(error, axis=1)
        improved = size < 0.99 * best[active]
        improved_at[active[improved]] = k
        best[active] = np.minimum(best[active], size)
        # At a limit, or in a far local minimum (a clamped search has its own cap, iterations:
        # its active set may crawl along a limit for a while before it frees a joint). A target
        # the pull holds off is let go of the pull first, to finish it.
        stuck = (k - improved_at[active] > STALL) & (not clamp)
        release = stuck & pulling[active]
        pulling[active[release]] = False
        improved_at[active[release]] = k
        keep = ~done & (~stuck | release)
        active, A, error = active[keep], J[keep][:, rows], error[keep]  # A: (N, r, n)
        if not len(active):
            break
        toward = (hint[active] - q[active]) * pulling[active, None]
        step = _step(A, error, toward)
        if clamp:
            # A joint at a limit that the step would push beyond it stays there, and the others
            # take up its share (the arm is redundant for a position): an active set.
            at_low, at_high = q[active] <= robot.limits[:, 0], q[active] >= robot.limits[:, 1]
            blocked = (at_low & (step < 0)) | (at_high & (step > 0))
            if blocked.any():
                step = _step(A * ~blocked[:, None, :], error, toward)
                step[blocked] = 0.0
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        q[active] += step * np.minimum(1.0, MAX_STEP_RAD / np.maximum(norm, 1e-300))
        if clamp:
            q[active] = np.clip(q[active], robot.limits[:, 0], robot.limits[:, 1])
    T, J = _tcp_state(robot, params, q, frame, tcp, moving)
    error = _errors(T, targets, pose)
    residual_m = np.linalg.norm(error[:, -3:], axis=1)
    residual_rad = np.linalg.norm(error[:, :3], axis=1) if pose else None
    q = wrap_into_limits(robot.limits, q, robot.prismatic)
    reached = residual_m <= tol_m
    if pose:
        reached &= residual_rad <= tol_rad
    within = np.all((q >= robot.limits[:, 0]) & (q <= robot.limits[:, 1]), axis=1)
    smallest = np.linalg.svd(J[:, rows], compute_uv=False)[:, -1]
    status = np.where(
        ~reached,
        "unreachable",
        np.where(~within, "outside joint limits", np.where(smallest < singular_tol, "near singularity", "ok")),
    )
    return IKResult(q, status, residual_m, residual_rad)
