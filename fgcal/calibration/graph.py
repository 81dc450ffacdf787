"""The factor graph of one stage: the parameter vector P (released parameters), the
auxiliary unknowns and the measurement factors, each of which depends directly on P.

There are no per-configuration pose variables: every measurement factor computes the pose
of its configuration from P through one vectorised kinematics evaluation shared by the
whole graph (fgcal.calibration.batch), so a linearisation costs one kinematics pass.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..factors import (
    Distances,
    MeasurementSet,
    ParameterBoundFactor,
    PointPairs,
    Poses,
    Projections,
    RobustLoss,
    SocketSpacings,
    StaticProjections,
    TouchPoints,
    TrackerPoints,
    gaussian,
)
from ..parameters import is_joint_length
from .batch import BatchKinematics
from .initialise import dataset_intrinsics
from .problem import Problem
from .state import State

P_KEY = gtsam.symbol("p", 0)
FIXTURE_KEY = gtsam.symbol("f", 0)
TRACKER_KEY = gtsam.symbol("l", 0)
OBJECT_KEY = gtsam.symbol("o", 0)
INTRINSICS_KEY = gtsam.symbol("k", 0)
TOOL_POINTS_KEY = gtsam.symbol("s", 0)
FIXED_POINTS_KEY = gtsam.symbol("a", 0)
TOOL_POSE_KEY = gtsam.symbol("e", 0)


@dataclass
class StageGraph:
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    model: BatchKinematics
    released: list[str]
    measurements: list[MeasurementSet] = field(default_factory=list)
    # Per measurement set, the problem's observation index of each robust unit (pixels and
    # tracker points; pair groups have none), for naming rejected measurements.
    observations: list[np.ndarray | None] = field(default_factory=list)
    aux: dict[int, tuple[str, int]] = field(default_factory=dict)  # key -> (name, dim)
    robust_scale: float | None = None  # scale of the robust loss's threshold, when there is one
    priors: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)  # non-measurement factors
    measurement_graphs: list[gtsam.NonlinearFactorGraph] = field(default_factory=list)  # each set's factors

    @property
    def params_key(self) -> int | None:
        return P_KEY if self.released else None


def build_graph(problem: Problem, released: Sequence[str], state: State) -> StageGraph:
    config = problem.config
    model = BatchKinematics(problem.robot, state.params, released, problem.q_fit, problem.frame)
    stage = StageGraph(gtsam.NonlinearFactorGraph(), gtsam.Values(), model, list(released))
    if released:
        stage.values.insert(P_KEY, model.base[model.index])
    nominal = problem.robot.nominal_parameters()
    bounded = [i for i, name in enumerate(released) if is_joint_length(name)]
    if bounded:
        _add_prior(
            stage,
            ParameterBoundFactor(
                P_KEY,
                len(released),
                np.array(bounded),
                np.array([nominal[released[i]] for i in bounded]),
                np.full(len(bounded), config.length_bound_m),
            ).factor,
        )
    if config.formulation == "pairs":
        make, robust = _pairs(problem, state, stage), config.robust["camera_points"]
    elif config.formulation == "projection":
        make, robust = _projection(problem, state, stage), config.robust["pixels"]
    elif config.formulation == "touch":
        make, robust = _touch(problem, state, stage), config.robust["touch_points"]
    elif config.formulation == "poses":
        make, robust = _poses(problem, state, stage), config.robust["tracker_poses"]
    elif config.formulation == "distances":
        make, robust = _distances(problem, state, stage), config.robust["distances"]
    elif config.formulation == "static_camera":
        make, robust = _static_camera(problem, state, stage), config.robust["pixels"]
    else:
        make, robust = _tracker(problem, state, stage), config.robust["tracker_points"]
    measurements, order = make(None)
    if robust is not None:
        # The loss's threshold is in units of the residuals' robust scale at the stage's start.
        kind, threshold = robust
        stage.robust_scale = robust_scale([measurements], stage.values)
        measurements, order = make(RobustLoss(kind, threshold * stage.robust_scale))
    _add_measurements(stage, measurements, order)
    if config.formulation == "touch" and problem.spacings:
        spacings = SocketSpacings(
            FIXED_POINTS_KEY,
            len(problem.touch_points),
            np.array([(a, b) for a, b, _ in problem.spacings]),
            np.array([d for _, _, d in problem.spacings]),
            config.spacing_sigma_m,
        )
        _add_measurements(stage, spacings, None)
    return stage


def _add_measurements(stage: StageGraph, measurements: MeasurementSet, order: np.ndarray | None) -> None:
    stage.measurements.append(measurements)
    stage.observations.append(order)
    factors = gtsam.NonlinearFactorGraph()
    for factor in measurements.factors():
        factors.add(factor.factor)
    stage.measurement_graphs.append(factors)
    stage.graph.push_back(factors)


def _add_prior(stage: StageGraph, factor) -> None:
    stage.graph.add(factor)
    stage.priors.add(factor)


def linearize(stage: StageGraph, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
    """The stage graph linearised at ``values``, each measurement set as one Jacobian factor
    (its rows are exactly those of its per-group factors, evaluated at once, without a
    callback per factor), the priors as GTSAM linearises them."""
    linear = stage.priors.linearize(values)
    for measurements, factors in zip(stage.measurements, stage.measurement_graphs, strict=True):
        if len(measurements.variables) > 3:  # GTSAM's Python JacobianFactor takes up to three keys
            linear.push_back(factors.linearize(values))
            continue
        evaluation = measurements.whitened(measurements.read(values), True)
        arguments = []
        for (key, _, _), block in zip(measurements.variables, evaluation.blocks, strict=True):
            arguments += [key, block]
        unit = gtsam.noiseModel.Unit.Create(measurements.n_rows)
        linear.push_back(gtsam.JacobianFactor(*arguments, -evaluation.residual, unit))
    return linear


def stage_error(stage: StageGraph, values: gtsam.Values) -> float:
    """The graph's error (half the sum of squared whitened residuals, robust losses applied)
    from the measurement sets' vectorised residuals and the priors."""
    error = stage.priors.error(values)
    for measurements in stage.measurements:
        residual = measurements.whitened(measurements.read(values), False).residual
        error += 0.5 * float(residual @ residual)
    return error


def robust_scale(measurements: list[MeasurementSet], values: gtsam.Values) -> float:
    """Robust scale of the whitened residuals, at least 1: the median norm of the robust
    units over the median of a chi distribution of their dimension (1.4826 MAD for 1-D).

    A robust loss's threshold is in units of this scale: while the model is still far off,
    residuals are many sigmas and a fixed 3-sigma threshold would treat them all as
    outliers; once the model fits, the scale returns to 1 and the threshold to k sigma.
    """
    scaled = []
    for m in measurements:
        scaled.append(m.unit_norms(values) / chi_median(m.unit_dims))
    if not scaled:
        return 1.0
    return max(1.0, float(np.median(np.concatenate(scaled))))


# Medians of the chi distribution for 1..12 degrees of freedom (sqrt(2 gammaincinv(k/2, 1/2)),
# from scipy.special, which costs a seventh of a second to import).
_CHI_MEDIANS = np.array(
    [0.67449, 1.17741, 1.538172, 1.832128, 2.086015, 2.3126, 2.519089, 2.710004, 2.888396, 3.056439, 3.215742, 3.36754]
)


def chi_median(dims: np.ndarray) -> np.ndarray:
    """Median of the norm of a standard normal vector of ``dims`` components (1-D: 0.6745);
    beyond 12 components Wilson-Hilferty's approximation (relative error below 2e-4)."""
    k = np.asarray(dims, dtype=int)
    approximate = np.sqrt(k * (1.0 - 2.0 / (9.0 * np.maximum(k, 1))) ** 3)
    return np.where(k <= len(_CHI_MEDIANS), _CHI_MEDIANS[np.clip(k, 1, len(_CHI_MEDIANS)) - 1], approximate)


def _pairs(problem: Problem, state: State, stage: StageGraph):
    fixture_key = None
    if state.fixture_rotation is not None:
        fixture_key = FIXTURE_KEY
        _add_variable(stage, FIXTURE_KEY, gtsam.Rot3(state.fixture_rotation), "fixture.r", 3)
    groups = [(np.array(g.images)[g.owner], g.c, g.p_F) for g in problem.pairs]

    def make(robust):
        pairs = PointPairs(
            stage.model,
            stage.params_key,
            groups,
            problem.config.camera_point_sigma_m,
            fixture_key=fixture_key,
            fixture_rotation=problem.fixture_rotation,
            robust=robust,
        )
        return pairs, None

    return make


def _add_variable(stage: StageGraph, key: int, value, name: str, dim: int) -> None:
    """An auxiliary unknown of the stage: its starting value and its (name, tangent dimension)."""
    stage.values.insert(key, value)
    stage.aux[key] = (name, dim)


def _by_configuration(observations: list) -> tuple[list, np.ndarray]:
    """Observations ``(configuration index, ...)`` ordered by configuration (a configuration's
    together, as one factor per configuration or image needs), and that order."""
    order = np.argsort([o[0] for o in observations], kind="stable")
    return [observations[i] for i in order], order


def _intrinsics(problem: Problem, state: State, stage: StageGraph) -> tuple[np.ndarray | None, int | None]:
    """The intrinsics as a constant (the dataset's), or as a variable with a prior from the
    earlier intrinsic calibration when the config estimates them: (constant, key)."""
    config = problem.config
    if state.intrinsics is not None:
        # Estimated, with a prior from the earlier intrinsic calibration (the dataset's values).
        _add_variable(stage, INTRINSICS_KEY, state.intrinsics, "intrinsics", 9)
        _add_prior(
            stage,
            gtsam.PriorFactorVector(
                INTRINSICS_KEY, dataset_intrinsics(problem), gaussian(np.array(config.intrinsics_prior_sigmas))
            ),
        )
        return None, INTRINSICS_KEY
    return dataset_intrinsics(problem), None


def _projection(problem: Problem, state: State, stage: StageGraph):
    config = problem.config
    _add_variable(stage, OBJECT_KEY, gtsam.Pose3(state.fixture_pose), "fixture", 6)
    constant, key = _intrinsics(problem, state, stage)
    observations, order = _by_configuration(problem.pixel_obs)  # an image's pixels together

    def make(robust):
        projections = Projections(
            stage.model,
            stage.params_key,
            OBJECT_KEY,
            np.array([o[0] for o in observations]),
            np.array([o[1] for o in observations]),
            np.array([o[2] for o in observations]),
            config.pixel_sigma_px,
            intrinsics=constant,
            intrinsics_key=key,
            robust=robust,
        )
        return projections, order

    return make


def _tracker(problem: Problem, state: State, stage: StageGraph):
    config = problem.config
    _add_variable(stage, TRACKER_KEY, gtsam.Pose3(state.tracker_pose), "tracker", 6)
    _add_variable(
        stage,
        TOOL_POINTS_KEY,
        np.asarray(state.tool_points, dtype=float).reshape(-1),
        "tool_points",
        3 * len(state.tool_points),
    )
    observations, order = _by_configuration(problem.tracker_obs)  # a configuration's points together

    def make(robust):
        points = TrackerPoints(
            stage.model,
            stage.params_key,
            TRACKER_KEY,
            TOOL_POINTS_KEY,
            len(state.tool_points),
            np.array([o[0] for o in observations]),
            np.array([o[1] for o in observations]),
            np.array([o[2] for o in observations]),
            config.tracker_sigma_m,
            robust=robust,
        )
        return points, order

    return make


def _tool_and_fixed_points(state: State, stage: StageGraph, observations: list, name: str):
    """The tool point (a probe, a ball) and the fixed points in W (sockets, pivots) as
    variables; the observations ordered by configuration, and that order."""
    _add_variable(stage, TOOL_POINTS_KEY, np.asarray(state.tool_points[0], dtype=float), "tool_points", 3)
    if len(state.fixed_points):  # distances between configurations alone have no fixed point
        _add_variable(stage, FIXED_POINTS_KEY, np.asarray(state.fixed_points, dtype=float).reshape(-1), name,
                      3 * len(state.fixed_points))  # fmt: skip
    return _by_configuration(observations)


def _touch(problem: Problem, state: State, stage: StageGraph):
    observations, order = _tool_and_fixed_points(state, stage, problem.touch_obs, "touch_points")

    def make(robust):
        touches = TouchPoints(
            stage.model,
            stage.params_key,
            TOOL_POINTS_KEY,
            FIXED_POINTS_KEY,
            len(state.fixed_points),
            np.array([o[0] for o in observations]),
            np.array([o[1] for o in observations]),
            problem.config.touch_sigma_m,
            robust=robust,
        )
        return touches, order

    return make


def _static_camera(problem: Problem, state: State, stage: StageGraph):
    config = problem.config
    _add_variable(stage, TRACKER_KEY, gtsam.Pose3(state.tracker_pose), "camera", 6)
    _add_variable(stage, TOOL_POSE_KEY, gtsam.Pose3(state.tool_pose), "board", 6)
    constant, key = _intrinsics(problem, state, stage)
    observations, order = _by_configuration(problem.pixel_obs)  # an image's pixels together

    def make(robust):
        projections = StaticProjections(
            stage.model,
            stage.params_key,
            TRACKER_KEY,
            TOOL_POSE_KEY,
            np.array([o[0] for o in observations]),
            np.array([o[1] for o in observations]),
            np.array([o[2] for o in observations]),
            config.pixel_sigma_px,
            intrinsics=constant,
            intrinsics_key=key,
            robust=robust,
        )
        return projections, order

    return make


def _poses(problem: Problem, state: State, stage: StageGraph):
    config = problem.config
    _add_variable(stage, TRACKER_KEY, gtsam.Pose3(state.tracker_pose), "tracker", 6)
    _add_variable(stage, TOOL_POSE_KEY, gtsam.Pose3(state.tool_pose), "probe", 6)
    observations, order = _by_configuration(problem.pose_obs)

    def make(robust):
        poses = Poses(
            stage.model,
            stage.params_key,
            TRACKER_KEY,
            TOOL_POSE_KEY,
            np.array([o[0] for o in observations]),
            [o[1] for o in observations],
            config.pose_sigma_rad,
            config.pose_sigma_m,
            robust=robust,
        )
        return poses, order

    return make


def _distances(problem: Problem, state: State, stage: StageGraph):
    observations, order = _tool_and_fixed_points(state, stage, problem.distance_obs, "pivots")

    def make(robust):
        distances = Distances(
            stage.model,
            stage.params_key,
            TOOL_POINTS_KEY,
            FIXED_POINTS_KEY if len(state.fixed_points) else None,
            len(state.fixed_points),
            np.array([o[0] for o in observations]),
            np.array([o[1] for o in observations]),
            np.array([o[2] for o in observations]),
            problem.config.distance_sigma_m,
            robust=robust,
            others=np.array([o[3] for o in observations]),
        )
        return distances, order

    return make


def read_state(stage: StageGraph, values: gtsam.Values, previous: State) -> State:
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
    if previous.tool_points is not None:
        state.tool_points = values.atVector(TOOL_POINTS_KEY).reshape(-1, 3)
    if previous.fixed_points is not None:
        state.fixed_points = (
            values.atVector(FIXED_POINTS_KEY).reshape(-1, 3) if len(previous.fixed_points) else previous.fixed_points
        )
    if previous.tool_pose is not None:
        state.tool_pose = values.atPose3(TOOL_POSE_KEY).matrix()
    return state
