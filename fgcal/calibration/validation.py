"""Positioning error on configurations not used for fitting.

- Pair formulation: the error at a tool point in the camera frame (default: the mean of the
  measured points, i.e. where the camera works), in W. The relative formulation cannot fix
  the robot's position in W (the base translation is a gauge; with an estimated fixture
  orientation also its rotation), so the common offset (or best rigid motion) over the held-out
  configurations is removed before scoring. The camera origin's error is reported too.
- Tracker formulation: the predicted reflector positions in the tracker frame; no gauge.
- Touch formulation: the predicted probe position at each held-out touch against the touched
  point's estimate (both in W); no gauge. Against the truth, the probe's position in W with
  the best rigid motion removed (W is where the nominal base puts it).
- Distances (ballbar): each held-out reading against the predicted distance from the ball to
  its pivot. Against the truth, as touches: the ball in W, the best rigid motion removed.
- Poses (6D probe): the predicted probe origin in the tracker frame against the measured one,
  and the angle between the predicted and measured orientations; no gauge. Against the truth,
  the probe origin in the tracker frame.
- Static camera: each held-out pixel's reprojection error, in the board's plane (m) as for
  projection. Against the truth, the board's origin in W with the best rigid motion removed:
  the robot's accuracy, not how well the camera knows its own depth (its pose's uncertainty
  would otherwise dominate the score).

Here against held-out measurements (the tracker's); against a simulation's ground truth in
fgcal.calibration.scoring, called after the calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..errors import InputError
from ..factors import Distances, MeasurementSet, PointPairs, Poses, Projections, StaticProjections, TouchPoints
from ..se3 import kabsch, pose, quaternion_rotation, transform_points
from .batch import BatchKinematics
from .graph import FIXED_POINTS_KEY, INTRINSICS_KEY, OBJECT_KEY, P_KEY, TOOL_POINTS_KEY, TOOL_POSE_KEY, TRACKER_KEY
from .initialise import dataset_intrinsics
from .problem import Problem, between_configurations, fitting_rows, pair_groups
from .state import State


@dataclass
class ErrorStats:
    mean: float
    rms: float
    max: float
    errors: np.ndarray  # norms
    axis_rms: np.ndarray | None = None  # (3,) RMS per axis of the error vectors, where there are vectors

    def as_dict(self) -> dict:
        if not self.errors.size:
            return {"mean": None, "rms": None, "p50": None, "p95": None, "max": None}
        p50, p95 = np.percentile(self.errors, [50, 95])
        out = {"mean": self.mean, "rms": self.rms, "p50": float(p50), "p95": float(p95), "max": self.max}
        if self.axis_rms is not None:
            out.update({f"rms_{axis}": float(v) for axis, v in zip("xyz", self.axis_rms, strict=True)})
        return out


def stats(errors: np.ndarray) -> ErrorStats:
    """Statistics of error norms (N,) or of error vectors (N, 3), whose norms they then use
    and whose RMS per axis they add."""
    errors = np.asarray(errors, dtype=float)
    if errors.size == 0:
        return ErrorStats(float("nan"), float("nan"), float("nan"), np.zeros(0))
    axis_rms = None
    if errors.ndim == 2:
        axis_rms = np.sqrt(np.mean(errors**2, axis=0))
        errors = np.linalg.norm(errors, axis=1)
    return ErrorStats(float(errors.mean()), float(np.sqrt(np.mean(errors**2))), float(errors.max()), errors, axis_rms)


# Held-out scores, in order of preference, with their label (all in m).
SCORES = {
    "tool_point": "position error",
    "distance": "distance error",
    "point_pair": "point-pair error",
    "reprojection": "reprojection error",
}
# Formulations whose tool point (a probe, a ball) is an unknown 3-vector, and whose fixed
# points (sockets, pivots) are estimated in W: scored against the truth up to a rigid motion.
FIXED_POINT_FORMULATIONS = ("touch", "distances")
# Formulations whose instrument (a 6D tracker, a static camera) sees a frame E on the flange.
CHAIN_FORMULATIONS = ("poses", "static_camera")


def primary_score(validation: dict, label: str) -> tuple[str, ErrorStats] | None:
    """The main held-out score of ``label`` ('before' or 'after'): the positioning error where
    there is one (truth, tracker), else the held-out point pairs."""
    scores = validation.get(label, {})
    for key in SCORES:
        if key in scores and scores[key].errors.size:
            return key, scores[key]
    return None


def remove_gauge(predicted: np.ndarray, reference: np.ndarray, gauge: str) -> np.ndarray:
    """Residual positions after removing the gauge: 'none', 'translation' or 'rigid'."""
    if gauge == "none":
        return predicted - reference
    if gauge == "translation":
        difference = predicted - reference
        return difference - difference.mean(axis=0)
    R, t = kabsch(predicted, reference)
    return predicted @ R.T + t - reference


def default_tool_point(problem: Problem, state: State) -> np.ndarray:
    """The scored tool point (m): the touch probe or the ballbar's ball, the origin of the 6D
    probe or of the board (flange frame), else the mean measured point in the camera frame,
    where the camera works."""
    if problem.config.formulation in FIXED_POINT_FORMULATIONS:
        return state.tool_points[0].copy()
    if problem.config.formulation in CHAIN_FORMULATIONS:
        return state.tool_pose[:3, 3].copy()
    table = problem.dataset.tables.get("camera_points")
    return table.values.mean(axis=0) if table is not None and len(table) else np.zeros(3)


def gauge_of(problem: Problem) -> str:
    """The gauge removed before scoring against the truth."""
    if problem.config.formulation in ("tracker", "poses"):
        return "none"  # scored in the tracker's frame, which the data fix
    if problem.config.formulation in (*FIXED_POINT_FORMULATIONS, "static_camera"):
        return "rigid"  # scored in W, where the nominal base puts the robot
    if problem.config.formulation == "projection":
        # The fixture pose is estimated relative to the robot: W is tied to the nominal base.
        return "rigid"
    return "rigid" if problem.config.fixture_orientation == "estimate" else "translation"


def predicted_positions(
    problem: Problem, state: State, q: np.ndarray, point: np.ndarray | None, target_index: int | None
) -> np.ndarray:
    robot = problem.robot
    params = robot.parameter_dict(state.params)
    if problem.config.formulation == "tracker":
        return transform_points(state.tracker_pose @ robot.fk(q, params), state.tool_points[target_index])
    if problem.config.formulation in FIXED_POINT_FORMULATIONS:  # the state's own probe or ball
        return transform_points(robot.fk(q, params), state.tool_points[0])
    if problem.config.formulation == "poses":  # the probe's origin, in the tracker's frame
        return transform_points(state.tracker_pose @ robot.fk(q, params), state.tool_pose[:3, 3])
    if problem.config.formulation == "static_camera":  # the board's origin, in W
        return transform_points(robot.fk(q, params), state.tool_pose[:3, 3])
    return transform_points(robot.fk_tool(q, params), point)


def held_out_pairs(problem: Problem, state: State, released: list[str]) -> PointPairs | None:
    """The point-pair contrasts of the held-out images, grouped as the fitting images are, at
    the state's parameters (P variable over ``released``, for the Jacobian)."""
    rejected = {(r["config"], r["point"]) for r in problem.rejected if r["kind"] == "camera_points"}
    groups = pair_groups(problem, problem.test, rejected)
    if not groups:
        return None
    model = BatchKinematics(problem.robot, state.params, released, problem.dataset.q[problem.test], "tool")
    rotation = state.fixture_rotation if state.fixture_rotation is not None else problem.fixture_rotation
    return PointPairs(
        model,
        P_KEY if released else None,
        [(np.array(g.images)[g.owner], g.c, g.p_F) for g in groups],
        problem.config.camera_point_sigma_m,
        fixture_rotation=rotation,
    )


def held_out_projections(problem: Problem, state: State, released: list[str]) -> Projections | None:
    """The held-out images' pixels as projections of the fixture's points, at the state's
    parameters (P variable over ``released``), fixture pose and intrinsics (a variable when
    the calibration estimated them)."""
    points = problem.dataset.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    rows = sorted(
        ((i, points.values[where[name]], uv) for i, name, uv in fitting_rows(problem, problem.dataset.tables["pixels"],
         "point", problem.test)),
        key=lambda row: row[0],
    )  # fmt: skip
    if not rows:
        return None
    model = BatchKinematics(problem.robot, state.params, released, problem.dataset.q[problem.test], "tool")
    estimated = state.intrinsics is not None
    return Projections(
        model,
        P_KEY if released else None,
        OBJECT_KEY,
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]),
        np.array([r[2] for r in rows]),
        problem.config.pixel_sigma_px,
        intrinsics=None if estimated else dataset_intrinsics(problem),
        intrinsics_key=INTRINSICS_KEY if estimated else None,
    )


def held_out_measurements(problem: Problem, state: State, released: list[str]) -> tuple[MeasurementSet, list] | None:
    """The held-out measurements of the touch, distances, poses and static-camera formulations
    as one measurement set at the state's parameters (P variable over ``released``), and its
    inputs besides P (the state's auxiliary unknowns); None when nothing is held out."""
    config, data = problem.config, problem.dataset
    test = problem.test
    model = BatchKinematics(problem.robot, state.params, released, data.q[test], "flange")
    key = P_KEY if released else None
    if config.formulation == "touch":
        rows = sorted(
            (i, problem.touch_points.index(name))
            for i, name, _ in fitting_rows(problem, data.tables["touch_points"], "point", test)
        )
        if not rows:
            return None
        measurements = TouchPoints(
            model, key, TOOL_POINTS_KEY, FIXED_POINTS_KEY, len(problem.touch_points),
            np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), config.touch_sigma_m,
        )  # fmt: skip
        return measurements, [state.tool_points[0], state.fixed_points.reshape(-1)]
    if config.formulation == "distances":
        # A reading between configurations is held out when either end is; the other end may
        # be a fitting configuration, so the model spans both sets (held-out ones first).
        rows = []
        if "distances" in data.tables:
            rows += sorted(
                (i, problem.pivots.index(name), float(v[0]), -1)
                for i, name, v in fitting_rows(problem, data.tables["distances"], "pivot", test)
            )
        if "tool_distances" in data.tables:
            rows += [(a, -1, d, b) for a, b, d in between_configurations(problem, data.tables["tool_distances"], test,
                                                                         problem.fit)]  # fmt: skip
        if not rows:
            return None
        both = BatchKinematics(problem.robot, state.params, released, data.q[np.r_[test, problem.fit]], "flange")
        with_pivots = len(problem.pivots) > 0
        measurements = Distances(
            both, key, TOOL_POINTS_KEY, FIXED_POINTS_KEY if with_pivots else None, len(problem.pivots),
            np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
            config.distance_sigma_m, others=np.array([r[3] for r in rows]),
        )  # fmt: skip
        return measurements, [state.tool_points[0], *([state.fixed_points.reshape(-1)] if with_pivots else [])]
    chain = [gtsam.Pose3(state.tracker_pose), gtsam.Pose3(state.tool_pose)]
    if config.formulation == "poses":
        rows = sorted(
            ((i, pose(quaternion_rotation(v[3:]), v[:3]))
             for i, _, v in fitting_rows(problem, data.tables["tracker_poses"], "config", test)),
            key=lambda row: row[0],
        )  # fmt: skip
        if not rows:
            return None
        measurements = Poses(
            model, key, TRACKER_KEY, TOOL_POSE_KEY, np.array([r[0] for r in rows]), [r[1] for r in rows],
            config.pose_sigma_rad, config.pose_sigma_m,
        )  # fmt: skip
        return measurements, chain
    points = data.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    rows = sorted(
        ((i, points.values[where[name]], uv) for i, name, uv in fitting_rows(problem, data.tables["pixels"],
         "point", test)),
        key=lambda row: row[0],
    )  # fmt: skip
    if not rows:
        return None
    estimated = state.intrinsics is not None
    measurements = StaticProjections(
        model, key, TRACKER_KEY, TOOL_POSE_KEY,
        np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.array([r[2] for r in rows]),
        config.pixel_sigma_px,
        intrinsics=None if estimated else dataset_intrinsics(problem),
        intrinsics_key=INTRINSICS_KEY if estimated else None,
    )  # fmt: skip
    return measurements, [*chain, *([np.asarray(state.intrinsics, dtype=float)] if estimated else [])]


def projection_inputs(problem: Problem, state: State, params: np.ndarray | None) -> list:
    inputs = [] if params is None else [params]
    inputs.append(gtsam.Pose3(state.fixture_pose))
    if state.intrinsics is not None:
        inputs.append(np.asarray(state.intrinsics, dtype=float))
    return inputs


def pose_errors(poses: Poses, inputs: list) -> dict[str, np.ndarray]:
    """Per measured pose Z: the error vector (m) of the predicted origin of E, ``L X E``, in
    the instrument's frame, and the angle (rad) between the predicted and measured orientations."""
    tracker, tool = (p.matrix() for p in inputs[-2:])
    predicted = tracker @ poses.kinematics.poses(None)[poses.configs] @ tool
    measured = np.linalg.inv(np.array([Z.matrix() for Z in poses.measured_inverse]))
    relative = np.einsum("oji,ojk->oik", measured[:, :3, :3], predicted[:, :3, :3])
    angles = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return {"tool_point": predicted[:, :3, 3] - measured[:, :3, 3], "orientation_rad": angles}


def focal_px(problem: Problem, state: State) -> float:
    """Mean focal length (px): turns a pixel error at a point's depth into metres."""
    intrinsics = state.intrinsics if state.intrinsics is not None else dataset_intrinsics(problem)
    return 0.5 * float(intrinsics[0] + intrinsics[1])


def held_out_errors(problem: Problem, state: State) -> dict[str, np.ndarray]:
    """Error norms (m) on the held-out configurations against their measurements: the
    tracker's reflectors (``tool_point``); for pairs, the norm of each point-pair contrast of
    the held-out images (``point_pair``: a pair's residual over sqrt 2, the seed's eq. 3); for
    projection, each held-out pixel's reprojection error times its depth over the focal
    length (``reprojection``: the error in the object's plane, m).
    (Scores against a simulation's truth: fgcal.calibration.scoring.)"""
    data = problem.dataset
    if problem.config.formulation == "pairs":
        pairs = held_out_pairs(problem, state, [])
        if pairs is None:
            return {}
        residual = pairs.compute([], False).residual.reshape(-1, 3)
        return {"point_pair": np.linalg.norm(residual, axis=1)}
    if problem.config.formulation == "projection":
        projections = held_out_projections(problem, state, [])
        if projections is None:
            return {}
        inputs = projection_inputs(problem, state, None)
        pixels = np.linalg.norm(projections.compute(inputs, False).residual.reshape(-1, 2), axis=1)
        metric = pixels * projections.camera_points(inputs)[3][:, 2] / focal_px(problem, state)
        return {"reprojection": metric, "reprojection_px": pixels}
    if problem.config.formulation in (*FIXED_POINT_FORMULATIONS, *CHAIN_FORMULATIONS):
        held_out = held_out_measurements(problem, state, [])
        if held_out is None:
            return {}
        measurements, inputs = held_out
        residual = measurements.compute(inputs, False).residual
        if problem.config.formulation == "touch":
            return {"tool_point": residual.reshape(-1, 3)}
        if problem.config.formulation == "distances":
            return {"distance": np.abs(residual)}
        if problem.config.formulation == "poses":
            return pose_errors(measurements, inputs)
        pixels = np.linalg.norm(residual.reshape(-1, 2), axis=1)
        metric = pixels * measurements.camera_points(inputs)[3][:, 2] / focal_px(problem, state)
        return {"reprojection": metric, "reprojection_px": pixels}
    q = data.q[problem.test]
    errors = []
    # Held-out measurements: predict each reflector at every held-out configuration once.
    table = data.tables["tracker_points"]
    held_out = sorted({str(n) for _, n, _ in fitting_rows(problem, table, "target", problem.test)})
    for target in held_out:
        at, measured = held_out_target(problem, target)
        if target in problem.targets:
            predicted = predicted_positions(problem, state, q, None, problem.targets.index(target))[at]
            errors.append(predicted - measured)
        else:
            errors.append(test_point_errors(problem, state, target, q[at], measured))
    return {"tool_point": np.concatenate(errors) if errors else np.zeros(0)}


def declared_test_point(problem: Problem, state: State, target: str) -> np.ndarray | None:
    """A declared test point in the calibrated flange frame, or None. Declared positions are
    in the tool's drawing; when three or more fitting targets are declared too, the drawing is
    carried onto their estimates by the best rigid motion (the calibrated flange frame is an
    effective one: the last joint's errors move it, and the fitted targets with it), else the
    declared position is taken as it is."""
    declared = problem.config.validation_tool_points
    if target not in declared:
        return None
    anchors = [t for t in problem.targets if t in declared]
    point = np.array(declared[target], dtype=float)
    if len(anchors) < 3:
        return point
    R, t = kabsch(
        np.array([declared[a] for a in anchors]), state.tool_points[[problem.targets.index(a) for a in anchors]]
    )
    return R @ point + t


def test_point_errors(problem: Problem, state: State, target: str, q: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Error vectors (m, tracker frame) at a tool point the fit never saw, measured at ``q``:
    at its declared position (config ``validation.tool_points``: declared_test_point), else at its
    leave-one-out position, the mean of its other measurements carried back to the flange
    through the calibrated robot (the test point's position is then not scored, only how the
    robot moves it)."""
    T_T_n = state.tracker_pose @ problem.robot.fk(q, problem.robot.parameter_dict(state.params))
    declared = declared_test_point(problem, state, target)
    if declared is not None:
        return transform_points(T_T_n, declared) - measured
    if len(q) < 2:
        raise InputError(
            problem.config.path,
            "validation.tool_points",
            f"test point {target!r} is measured once in the validation set: declare its position on the flange, "
            "or measure it at several configurations (it is fitted leave-one-out)",
        )
    back = back_projections(T_T_n, measured)
    loo = (back.sum(axis=0) - back) / (len(q) - 1)
    return np.einsum("oij,oj->oi", T_T_n[:, :3, :3], loo) + T_T_n[:, :3, 3] - measured


def held_out_target(problem: Problem, target: str) -> tuple[np.ndarray, np.ndarray]:
    """Where a tracker target was measured at held-out configurations: their positions in
    ``problem.test`` and the measured points (tracker frame, m)."""
    rows = [(i, xyz) for i, name, xyz in fitting_rows(problem, problem.dataset.tables["tracker_points"], "target",
            problem.test) if name == target]  # fmt: skip
    return np.array([i for i, _ in rows], dtype=int), np.array([xyz for _, xyz in rows]).reshape(-1, 3)


def back_projections(T_T_n: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Measured points (tracker frame) carried back into the flange frame of each pose T_T_n."""
    return np.einsum("oji,oj->oi", T_T_n[:, :3, :3], measured - T_T_n[:, :3, 3])
