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
        probe, state.fixed_points = initial_touch(problem, params)
        state.tool_points = probe[None, :]
    if problem.config.formulation == "distances":
        ball, state.fixed_points = initial_ballbar(problem, params)
        state.tool_points = ball[None, :]
    if problem.config.formulation == "poses":
        flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
        state.tracker_pose, state.tool_pose = initial_pose_chain(
            flange[[j for j, _ in problem.pose_obs]], np.array([Z for _, Z in problem.pose_obs])
        )
    if problem.config.formulation == "static_camera":
        # The board's pose in the camera per image (solvePnP), then the chain through the robot.
        T_C_B = pnp_per_image(problem)
        flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
        images = sorted(T_C_B)
        state.tracker_pose, state.tool_pose = initial_pose_chain(flange[images], np.array([T_C_B[j] for j in images]))
        if problem.config.intrinsics_prior_sigmas is not None:
            state.intrinsics = dataset_intrinsics(problem)
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


def initial_pose_chain(flange: np.ndarray, measured: np.ndarray, rounds: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """L (the instrument's T_I_W) and E (the measured frame on the flange, T_n_E) from
    measured poses ``Z_j = L X_j E`` (N, 4, 4) and the flange poses X_j of the current model:
    OpenCV's calibrateHandEye (Park) in its eye-to-hand use (the flange poses inverted gives
    ``Y = L^-1`` and the constant E), then alternating averages of L and E (chordal mean of
    the rotations, mean of the translations), which settle the noise of the hand-eye step."""
    inverse_flange = np.linalg.inv(flange)
    R, t = cv2.calibrateHandEye(
        list(inverse_flange[:, :3, :3]),
        list(inverse_flange[:, :3, 3]),
        list(measured[:, :3, :3]),
        list(measured[:, :3, 3]),
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    W_from_instrument = np.eye(4)
    W_from_instrument[:3, :3], W_from_instrument[:3, 3] = R, np.ravel(t)
    L = np.linalg.inv(W_from_instrument)
    for _ in range(rounds):
        E = mean_pose(inverse_flange @ np.linalg.inv(L) @ measured)
        L = mean_pose(measured @ np.linalg.inv(flange @ E))
    return L, mean_pose(inverse_flange @ np.linalg.inv(L) @ measured)


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """Chordal mean of the rotations and mean of the translations of poses (N, 4, 4)."""
    U, _, Vt = np.linalg.svd(poses[:, :3, :3].sum(axis=0))
    T = np.eye(4)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return T


def initial_ballbar(problem: Problem, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool ball s (flange frame) and pivots a_k (W) from the nominal model, no guess needed.

    To pivots, ``|R_j s + t_j - a_k|^2 = d^2`` is linear in s, a_k, w_k = |s|^2 + |a_k|^2 and
    M_k = a_k s^T (the bilinear term a_k . R_j s = <R_j, M_k>); that least-squares solution,
    and a start with the ball at the flange centre whose pivots a sphere fit places, are each
    refined by nonlinear least squares on (s, a) alone, with the readings between
    configurations (``|R_j s + t_j - R_b s - t_b| = d``) too, and the better kept (m). With
    readings between configurations only, the starts are the flange centre and the nominal
    tool point."""
    from scipy.optimize import least_squares

    flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
    j = np.array([o[0] for o in problem.distance_obs])
    k = np.array([o[1] for o in problem.distance_obs])
    d = np.array([o[2] for o in problem.distance_obs])
    b = np.array([o[3] for o in problem.distance_obs])
    R, t = flange[j, :3, :3], flange[j, :3, 3]
    R_b, t_b = flange[np.maximum(b, 0), :3, :3], flange[np.maximum(b, 0), :3, 3]
    to_pivot = k >= 0
    n_pivots = len(problem.pivots)
    if n_pivots:
        starts = _pivot_starts(R[to_pivot], t[to_pivot], k[to_pivot], d[to_pivot], n_pivots)
    else:
        starts = [(np.zeros(3), np.zeros((0, 3))), (problem.robot.tool_pose[:3, 3], np.zeros((0, 3)))]

    def residual(x: np.ndarray) -> np.ndarray:
        s, pivots = x[:3], x[3:].reshape(-1, 3)
        end = np.where(to_pivot[:, None], pivots[np.maximum(k, 0)] if n_pivots else 0.0, R_b @ s + t_b)
        return np.linalg.norm(R @ s + t - end, axis=1) - d

    fits = [least_squares(residual, np.concatenate([s, a.reshape(-1)]), method="lm") for s, a in starts]
    best = min(fits, key=lambda fit: fit.cost)
    if not np.all(np.isfinite(best.x)) or np.sqrt(2 * best.cost / len(d)) > 0.05:
        table = "distances.csv" if n_pivots else "tool_distances.csv"
        raise InputError(
            problem.dataset.path / table,
            None,
            "the distances cannot locate the ball and the pivots (typical residual "
            f"{np.sqrt(2 * best.cost / len(d)) * 1e3:.3g} mm with the nominal robot): measure each pivot with "
            "the tool in clearly different positions and orientations",
        )
    return best.x[:3], best.x[3:].reshape(-1, 3)


def _pivot_starts(
    R: np.ndarray, t: np.ndarray, k: np.ndarray, d: np.ndarray, n_pivots: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Starts (s, pivots) from the readings to pivots: the linear lift and the sphere fits."""
    A = np.zeros((len(k), 3 + 13 * n_pivots))
    A[:, :3] = 2.0 * np.einsum("oji,oj->oi", R, t)
    rows = np.arange(len(k))
    A[rows, 3 + 13 * k] = 1.0
    for axis in range(3):
        A[rows, 4 + 13 * k + axis] = -2.0 * t[:, axis]
    for entry in range(9):
        A[rows, 7 + 13 * k + entry] = -2.0 * R.reshape(-1, 9)[:, entry]
    linear = np.linalg.lstsq(A, d**2 - np.sum(t * t, axis=1), rcond=None)[0]
    return [
        (linear[:3], np.array([linear[4 + 13 * p : 7 + 13 * p] for p in range(n_pivots)])),
        (np.zeros(3), np.array([_sphere_centre(t[k == p], d[k == p]) for p in range(n_pivots)])),
    ]


def _sphere_centre(points: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Centre a of the sphere through points at known distances: ``2 p.a - |a|^2 = |p|^2 - d^2``
    is linear in (a, |a|^2)."""
    A = np.hstack([2.0 * points, -np.ones((len(points), 1))])
    return np.linalg.lstsq(A, np.sum(points**2, axis=1) - radii**2, rcond=None)[0][:3]


def dataset_intrinsics(problem: Problem) -> np.ndarray:
    camera = problem.dataset.camera
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])
