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

Here against held-out measurements (the tracker's); against a simulation's ground truth in
fgcal.calibration.scoring, called after the calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..factors import PointPairs, Projections, TouchPoints
from ..se3 import kabsch, transform_points
from .batch import BatchKinematics
from .graph import INTRINSICS_KEY, OBJECT_KEY, P_KEY, SOCKETS_KEY, TOOL_POINTS_KEY
from .initialise import dataset_intrinsics
from .problem import Problem, fitting_rows, pair_groups
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
SCORES = {"tool_point": "position error", "point_pair": "point-pair error", "reprojection": "reprojection error"}


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
    """The scored tool point (m): the touch probe (flange frame), else the mean measured point
    in the camera frame, where the camera works."""
    if problem.config.formulation == "touch":
        return state.tool_points[0].copy()
    table = problem.dataset.tables.get("camera_points")
    return table.values.mean(axis=0) if table is not None and len(table) else np.zeros(3)


def gauge_of(problem: Problem) -> str:
    """The gauge removed before scoring against the truth."""
    if problem.config.formulation == "tracker":
        return "none"
    if problem.config.formulation == "touch":
        return "rigid"  # the touched points are estimated in the frame of the nominal base
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
    if problem.config.formulation == "touch":  # the state's own probe
        return transform_points(robot.fk(q, params), state.tool_points[0])
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


def held_out_touches(problem: Problem, state: State, released: list[str]) -> TouchPoints | None:
    """The held-out touches, at the state's parameters (P variable over ``released``), probe
    and touched points."""
    rows = sorted(
        (i, problem.touch_points.index(name))
        for i, name, _ in fitting_rows(problem, problem.dataset.tables["touch_points"], "point", problem.test)
    )
    if not rows:
        return None
    model = BatchKinematics(problem.robot, state.params, released, problem.dataset.q[problem.test], "flange")
    return TouchPoints(
        model,
        P_KEY if released else None,
        TOOL_POINTS_KEY,
        SOCKETS_KEY,
        len(problem.touch_points),
        np.array([r[0] for r in rows]),
        np.array([r[1] for r in rows]),
        problem.config.touch_sigma_m,
    )


def touch_inputs(state: State, params: np.ndarray | None) -> list:
    return [*([] if params is None else [params]), state.tool_points[0], state.sockets.reshape(-1)]


def projection_inputs(problem: Problem, state: State, params: np.ndarray | None) -> list:
    inputs = [] if params is None else [params]
    inputs.append(gtsam.Pose3(state.fixture_pose))
    if state.intrinsics is not None:
        inputs.append(np.asarray(state.intrinsics, dtype=float))
    return inputs


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
    if problem.config.formulation == "touch":
        touches = held_out_touches(problem, state, [])
        if touches is None:
            return {}
        return {"tool_point": touches.compute(touch_inputs(state, None), False).residual.reshape(-1, 3)}
    q = data.q[problem.test]
    errors = []
    # Held-out measurements: predict each reflector at every held-out configuration once.
    table = data.tables["tracker_points"]
    config_pos = {c: i for i, c in enumerate(data.configs)}
    test_pos = {int(c): i for i, c in enumerate(problem.test)}
    for t, target in enumerate(problem.targets):
        rows = [
            (test_pos[config_pos[cid]], xyz)
            for cid, name, xyz in zip(table.ids["config"], table.ids["target"], table.values, strict=True)
            if name == target and config_pos[cid] in test_pos
        ]
        if rows:
            predicted = predicted_positions(problem, state, q, None, t)[[i for i, _ in rows]]
            errors.append(predicted - np.array([xyz for _, xyz in rows]))
    return {"tool_point": np.concatenate(errors) if errors else np.zeros(0)}
