"""The factor graph of one stage: parameter vector P (released parameters), a pose
variable per fitting configuration, auxiliary unknowns and the measurement factors."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import gtsam
import numpy as np

from ..camera import solve_pnp
from ..errors import InputError
from ..factors import (
    KinematicFactor,
    ParameterBoundFactor,
    PointPairFactor,
    ProjectionFactor,
    TrackerPointFactor,
    gaussian,
)
from ..parameters import split_name
from ..se3 import so3_log, transform_points
from .batch import BatchKinematics
from .problem import Problem

P_KEY = gtsam.symbol("p", 0)
FIXTURE_KEY = gtsam.symbol("f", 0)
TRACKER_KEY = gtsam.symbol("l", 0)
OBJECT_KEY = gtsam.symbol("o", 0)
INTRINSICS_KEY = gtsam.symbol("k", 0)


def pose_key(j: int) -> int:
    return gtsam.symbol("x", j)


def point_key(t: int) -> int:
    return gtsam.symbol("s", t)


@dataclass
class State:
    """Current estimate of everything: full parameter vector (SI) and auxiliary unknowns."""

    params: np.ndarray
    fixture_rotation: np.ndarray | None = None  # R_W_F, when estimated
    tracker_pose: np.ndarray | None = None  # T_T_W
    tool_points: np.ndarray | None = None  # (m, 3) in the flange frame
    fixture_pose: np.ndarray | None = None  # T_W_F, when the projection formulation estimates it
    intrinsics: np.ndarray | None = None  # (fx, fy, cx, cy, k1, k2, p1, p2, k3), when estimated


@dataclass
class StageGraph:
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    model: BatchKinematics
    released: list[str]
    measurements: list = field(default_factory=list)
    pose_index: dict[int, int] = field(default_factory=dict)
    aux: dict[int, tuple[str, int]] = field(default_factory=dict)  # key -> (name, dim)
    robust_scale: float | None = None  # scale of the robust loss's threshold, when there is one


def initial_state(problem: Problem) -> State:
    params = problem.robot.parameter_vector()
    state = State(params)
    if problem.config.formulation == "pairs" and problem.config.fixture_orientation == "estimate":
        state.fixture_rotation = problem.fixture_rotation.copy()
    if problem.config.formulation == "tracker":
        state.tracker_pose, state.tool_points = initial_tracker(problem, params)
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
    for j, p_F, uv in problem.pixel_obs:
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
    alternate a Kabsch fit of the tracker pose with a linear fit of the tool points."""
    flange = problem.robot.fk(problem.q_fit, problem.robot.parameter_dict(params))
    j = np.array([o[0] for o in problem.tracker_obs])
    t = np.array([o[1] for o in problem.tracker_obs])
    measured = np.array([o[2] for o in problem.tracker_obs])
    n_targets = len(problem.targets)
    points = np.zeros((n_targets, 3))
    R_L, t_L = np.eye(3), np.zeros(3)
    for _ in range(rounds):
        world = transform_points(flange[j], points[t])
        R_L, t_L = kabsch(world, measured)
        # m - R_L p_j = R_L R_j s_t + t_L: linear in the tool points and t_L.
        A = np.zeros((3 * len(j), 3 * n_targets + 3))
        for row, (jj, tt) in enumerate(zip(j, t, strict=True)):
            A[3 * row : 3 * row + 3, 3 * tt : 3 * tt + 3] = R_L @ flange[jj, :3, :3]
            A[3 * row : 3 * row + 3, -3:] = np.eye(3)
        b = (measured - flange[j, :3, 3] @ R_L.T).reshape(-1)
        solution = np.linalg.lstsq(A, b, rcond=None)[0]
        points = solution[:-3].reshape(n_targets, 3)
    T_L = np.eye(4)
    T_L[:3, :3], T_L[:3, 3] = R_L, t_L
    return T_L, points


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising |R source + t - target|."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    H = (source - mu_s).T @ (target - mu_t)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


def build_graph(problem: Problem, released: Sequence[str], state: State) -> StageGraph:
    config = problem.config
    model = BatchKinematics(problem.robot, state.params, released, problem.q_fit, problem.frame)
    p0 = model.base[model.index]
    poses = model.poses(p0)
    stage = StageGraph(gtsam.NonlinearFactorGraph(), gtsam.Values(), model, list(released))
    kinematic_sigmas = np.full(6, config.pose_tie_sigma)
    if released:
        stage.values.insert(P_KEY, p0)
    for j, T in enumerate(poses):
        key = pose_key(j)
        stage.values.insert(key, gtsam.Pose3(T))
        stage.pose_index[key] = j
        if released:
            stage.graph.add(KinematicFactor(P_KEY, key, j, model, kinematic_sigmas).factor)
        else:  # nothing released: the poses follow the current model exactly
            stage.graph.add(gtsam.PriorFactorPose3(key, gtsam.Pose3(T), gaussian(kinematic_sigmas)))
    nominal = problem.robot.nominal_parameters()
    bounded = [i for i, name in enumerate(released) if split_name(name)[0] in ("d", "a")]
    if bounded:
        stage.graph.add(
            ParameterBoundFactor(
                P_KEY,
                len(released),
                np.array(bounded),
                np.array([nominal[released[i]] for i in bounded]),
                np.full(len(bounded), config.length_bound_m),
            ).factor
        )
    if config.formulation == "pairs":
        _add_pairs(problem, state, stage)
    elif config.formulation == "projection":
        _add_projection(problem, state, stage)
    else:
        _add_tracker(problem, state, stage)
    return stage


def robust_scale(factors: list, values: gtsam.Values) -> float:
    """Robust scale of the whitened residuals (1.4826 MAD of their RMS per factor), at least 1.

    A robust loss's threshold is in units of this scale: while the model is still far off,
    residuals are many sigmas and a fixed 3-sigma threshold would treat them all as
    outliers; once the model fits, the scale returns to 1 and the threshold to k sigma.
    """
    norms = []
    for factor in factors:
        residual, _ = factor.checked(factor.read(values), False)
        norms.append(np.sqrt(np.mean((residual / factor.sigmas) ** 2)))
    return max(1.0, 1.4826 * float(np.median(norms))) if norms else 1.0


def _add_measurements(stage: StageGraph, make, robust: tuple[str, float] | None) -> None:
    """Create the measurement factors with ``make(noise_or_None) -> list``; with a robust
    loss, its threshold is scaled by the residuals' robust scale at the stage's start."""
    factors = make(None)
    if robust is not None:
        kind, threshold = robust
        stage.robust_scale = robust_scale(factors, stage.values)
        factors = make((kind, threshold * stage.robust_scale))
    for factor in factors:
        stage.graph.add(factor.factor)
    stage.measurements.extend(factors)


def _add_pairs(problem: Problem, state: State, stage: StageGraph) -> None:
    config = problem.config
    fixture_key = None
    if state.fixture_rotation is not None:
        fixture_key = FIXTURE_KEY
        stage.values.insert(FIXTURE_KEY, gtsam.Rot3(state.fixture_rotation))
        stage.aux[FIXTURE_KEY] = ("fixture.r", 3)

    def make(robust):
        factors = []
        for group in problem.pairs:
            sigmas = np.full(3 * (len(group.c) - 1), config.camera_point_sigma_m)
            factors.append(
                PointPairFactor(
                    [pose_key(j) for j in group.images],
                    group.owner,
                    group.c,
                    group.p_F,
                    gaussian(sigmas, robust),
                    sigmas,
                    fixture_key=fixture_key,
                    fixture_rotation=problem.fixture_rotation,
                )
            )
        return factors

    _add_measurements(stage, make, config.robust["camera_points"])


def dataset_intrinsics(problem: Problem) -> np.ndarray:
    camera = problem.dataset.camera
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])


def _add_projection(problem: Problem, state: State, stage: StageGraph) -> None:
    config = problem.config
    stage.values.insert(OBJECT_KEY, gtsam.Pose3(state.fixture_pose))
    stage.aux[OBJECT_KEY] = ("fixture", 6)
    sigmas = np.full(2, config.pixel_sigma_px)
    if state.intrinsics is not None:
        # Estimated, with a prior from the earlier intrinsic calibration (the dataset's values).
        stage.values.insert(INTRINSICS_KEY, state.intrinsics)
        stage.aux[INTRINSICS_KEY] = ("intrinsics", 9)
        stage.graph.add(
            gtsam.PriorFactorVector(
                INTRINSICS_KEY, dataset_intrinsics(problem), gaussian(np.array(config.intrinsics_prior_sigmas))
            )
        )
        constant, key = None, INTRINSICS_KEY
    else:
        constant, key = dataset_intrinsics(problem), None

    def make(robust):
        noise = gaussian(sigmas, robust)
        return [
            ProjectionFactor(pose_key(j), OBJECT_KEY, p_F, uv, noise, sigmas, intrinsics=constant, intrinsics_key=key)
            for j, p_F, uv in problem.pixel_obs
        ]

    _add_measurements(stage, make, config.robust["pixels"])


def _add_tracker(problem: Problem, state: State, stage: StageGraph) -> None:
    config = problem.config
    stage.values.insert(TRACKER_KEY, gtsam.Pose3(state.tracker_pose))
    stage.aux[TRACKER_KEY] = ("tracker", 6)
    for t, point in enumerate(state.tool_points):
        stage.values.insert(point_key(t), np.asarray(point, dtype=float))
        stage.aux[point_key(t)] = (f"tool_point.{problem.targets[t]}", 3)
    sigmas = np.full(3, config.tracker_sigma_m)

    def make(robust):
        noise = gaussian(sigmas, robust)
        return [
            TrackerPointFactor(TRACKER_KEY, pose_key(j), point_key(t), measured, noise, sigmas)
            for j, t, measured in problem.tracker_obs
        ]

    _add_measurements(stage, make, config.robust["tracker_points"])


def read_state(problem: Problem, stage: StageGraph, values: gtsam.Values, previous: State) -> State:
    params = stage.model.full(values.atVector(P_KEY)) if stage.released else previous.params.copy()
    state = State(params)
    if previous.fixture_rotation is not None:
        state.fixture_rotation = values.atRot3(FIXTURE_KEY).matrix()
    if previous.fixture_pose is not None:
        state.fixture_pose = values.atPose3(OBJECT_KEY).matrix()
    if previous.intrinsics is not None:
        state.intrinsics = values.atVector(INTRINSICS_KEY)
    if previous.tracker_pose is not None:
        state.tracker_pose = values.atPose3(TRACKER_KEY).matrix()
        state.tool_points = np.array([values.atPoint3(point_key(t)) for t in range(len(previous.tool_points))])
    return state
