"""Starting values of a calibration's auxiliary unknowns, from the measurements alone.

Nobody measured the tracker's pose, the reflectors on the tool, the fixture's pose or the
camera mounting to the precision a calibration needs: each starts from the data and the
nominal model (OpenCV's solvePnP per image and calibrateHandEye; Kabsch fits alternated with
linear fits of the tool points), before the graph is built.
"""

from __future__ import annotations

import itertools

import cv2
import numpy as np

from ..camera import solve_pnp
from ..errors import InputError
from ..se3 import kabsch, so3_log, transform_points
from .problem import Problem
from .state import State


def initial_state(problem: Problem) -> State:
    params = problem.robot.parameter_vector()
    state = State(params)
    if problem.config.formulation == "pairs" and problem.config.fixture_orientation == "estimate":
        state.fixture_rotation = problem.fixture_rotation.copy()
    if problem.config.formulation == "tracker":
        state.tracker_pose, state.tool_points = initial_tracker(problem, params)
    if problem.config.formulation == "touch":
        probe, state.sockets = initial_touch(problem, params)
        state.tool_points = probe[None, :]
    if problem.config.formulation == "projection":
        # Nobody measured the mounting or the fixture: both start from the images.
        T_C_F = pnp_per_image(problem)
        state.params = with_mounting(problem, params, hand_eye_mounting(problem, params, T_C_F))
        state.fixture_pose = initial_fixture_pose(problem, state.params, T_C_F)
        if problem.config.intrinsics_prior_sigmas is not None:
            state.intrinsics = dataset_intrinsics(problem)
    return state


def pnp_per_image(problem: Problem) -> dict[int, np.ndarray]:
    """T_C_F of every fitting image with at least four points, from OpenCV's solvePnP (IPPE)."""
    camera = problem.dataset.camera
    images: dict[int, list] = {}
    for j, p_F, uv, _ in problem.pixel_obs:
        images.setdefault(j, []).append((p_F, uv))
    poses = {}
    for j, obs in images.items():
        if len(obs) >= 4:
            T = solve_pnp(np.array([o[0] for o in obs]), np.array([o[1] for o in obs]), camera)
            if T is not None:
                poses[j] = T
    if len(poses) < 3:
        raise InputError(
            problem.dataset.path / "pixels.csv",
            None,
            f"solvePnP succeeded on {len(poses)} images: at least 3 with 4 points are needed",
        )
    return poses


def hand_eye_mounting(problem: Problem, params: np.ndarray, T_C_F: dict[int, np.ndarray]) -> np.ndarray:
    """Camera mounting T_n_C from OpenCV's calibrateHandEye (Park), with the flange poses of
    the current model and the per-image target poses."""
    flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
    images = sorted(T_C_F)
    R, t = cv2.calibrateHandEye(
        [flange[j][:3, :3] for j in images],
        [flange[j][:3, 3] for j in images],
        [T_C_F[j][:3, :3] for j in images],
        [T_C_F[j][:3, 3] for j in images],
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


def with_mounting(problem: Problem, params: np.ndarray, T_n_C: np.ndarray) -> np.ndarray:
    """Parameters whose tool.* perturbation turns the nominal mounting into ``T_n_C``."""
    local = np.linalg.inv(problem.robot.tool_pose) @ T_n_C
    names = problem.robot.parameter_names
    out = params.copy()
    out[names.index("tool.tx") : names.index("tool.tz") + 1] = local[:3, 3]
    out[names.index("tool.rx") : names.index("tool.rz") + 1] = so3_log(local[:3, :3])
    return out


def initial_fixture_pose(problem: Problem, params: np.ndarray, T_C_F: dict[int, np.ndarray]) -> np.ndarray:
    """T_W_F from the images: per-image T_C_F composed with the current camera pose, the
    rotations averaged (chordal mean), the translations by their median."""
    T_W_C = problem.robot.fk_tool(problem.q_fit, problem.robot.parameter_dict(params))
    stacked = np.array([T_W_C[j] @ T for j, T in T_C_F.items()])
    U, _, Vt = np.linalg.svd(stacked[:, :3, :3].sum(axis=0))
    T = np.eye(4)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T[:3, 3] = np.median(stacked[:, :3, 3], axis=0)
    return T


def initial_tracker(problem: Problem, params: np.ndarray, rounds: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """Tracker pose T_T_W and tool points from the nominal model, no guess needed:
    alternate a Kabsch fit of the tracker pose with a linear fit of the tool points and the
    tracker's position, from several starting orientations of the tracker (the 24 rotations
    of a cube, and the Kabsch fit of the flange origins), keeping the best fit. One start is
    not enough: when the flange origin barely moves (a positioner's table centre on its
    axes) the flange origins say nothing about the tracker's orientation, and the alternation
    from a wrong one settles in a false minimum half a metre off."""
    flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
    j = np.array([o[0] for o in problem.tracker_obs])
    t = np.array([o[1] for o in problem.tracker_obs])
    measured = np.array([o[2] for o in problem.tracker_obs])
    n_targets = len(problem.targets)
    R_j, p_j = flange[j, :3, :3], flange[j, :3, 3]

    def fit_points(R_L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # m - R_L p_j = R_L R_j s_t + t_L: linear in the tool points and t_L.
        A = np.zeros((len(j), 3, 3 * n_targets + 3))
        for target in range(n_targets):
            rows = t == target
            A[rows, :, 3 * target : 3 * target + 3] = R_L @ R_j[rows]
        A[:, :, -3:] = np.eye(3)
        b = measured - p_j @ R_L.T
        solution = np.linalg.lstsq(A.reshape(-1, A.shape[2]), b.reshape(-1), rcond=None)[0]
        return solution[:-3].reshape(n_targets, 3), solution[-3:]

    def refine(R_L: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        for _ in range(rounds):
            points, t_L = fit_points(R_L)
            R_L, t_L = kabsch(transform_points(flange[j], points[t]), measured)
        points, t_L = fit_points(R_L)
        world = np.einsum("oij,oj->oi", R_j, points[t]) + p_j
        cost = float(np.sum((world @ R_L.T + t_L - measured) ** 2))
        return cost, R_L, t_L, points

    starts = [kabsch(p_j, measured)[0], *cube_rotations()]
    _, R_L, t_L, points = min((refine(R) for R in starts), key=lambda fit: fit[0])
    T_L = np.eye(4)
    T_L[:3, :3], T_L[:3, 3] = R_L, t_L
    return T_L, points


def cube_rotations() -> list[np.ndarray]:
    """The 24 proper rotations that map the coordinate axes onto themselves."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            R[np.arange(3), perm] = signs
            if np.linalg.det(R) > 0:
                out.append(R)
    return out


def initial_touch(problem: Problem, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Touch probe s (flange frame) and touch points a_k (W) from the nominal model, no guess
    needed: ``R_j s - a_k = -p_j`` is linear in both, solved by least squares (m)."""
    flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
    n_points = len(problem.touch_points)
    A = np.zeros((3 * len(problem.touch_obs), 3 + 3 * n_points))
    b = np.zeros(3 * len(problem.touch_obs))
    for row, (j, k) in enumerate(problem.touch_obs):
        A[3 * row : 3 * row + 3, :3] = flange[j, :3, :3]
        A[3 * row : 3 * row + 3, 3 + 3 * k : 6 + 3 * k] = -np.eye(3)
        b[3 * row : 3 * row + 3] = -flange[j, :3, 3]
    solution, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
    if rank < A.shape[1]:
        raise InputError(
            problem.dataset.path / "touch_points.csv",
            None,
            "the touches cannot locate the probe: touch each point with the tool in clearly different orientations",
        )
    return solution[:3], solution[3:].reshape(n_points, 3)


def dataset_intrinsics(problem: Problem) -> np.ndarray:
    camera = problem.dataset.camera
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])
