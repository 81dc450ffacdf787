"""Positioning error on configurations not used for fitting.

- Pair formulation: the error at a tool point in the camera frame (default: the mean of the
  measured points, i.e. where the camera works), in W. The relative formulation cannot fix
  the robot's position in W (the base translation is a gauge; with an estimated fixture
  orientation also its rotation), so the common offset (or best rigid motion) over the held-out
  configurations is removed before scoring. The camera origin's error is reported too.
- Tracker formulation: the predicted reflector positions in the tracker frame; no gauge.

Here against held-out measurements (the tracker's); against a simulation's ground truth in
fgcal.calibration.scoring, called after the calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from .. import kinematics
from ..factors import PointPairs, Projections, TrackerPoints
from ..se3 import kabsch, skew, transform_points
from .batch import BatchKinematics
from .graph import INTRINSICS_KEY, OBJECT_KEY, P_KEY, TOOL_POINTS_KEY, TRACKER_KEY
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


def default_tool_point(problem: Problem) -> np.ndarray:
    """The mean measured point in the camera frame: where the camera works (m)."""
    table = problem.dataset.tables.get("camera_points")
    return table.values.mean(axis=0) if table is not None and len(table) else np.zeros(3)


def gauge_of(problem: Problem) -> str:
    if problem.config.formulation == "tracker":
        return "none"
    if problem.config.formulation == "projection":
        # The fixture pose is estimated relative to the robot: W is tied to the nominal base.
        return "rigid"
    return "rigid" if problem.config.fixture_orientation == "estimate" else "translation"


def predicted_positions(
    problem: Problem, state: State, q: np.ndarray, point: np.ndarray | None, target_index: int | None
) -> np.ndarray:
    robot = problem.robot
    params = robot.parameter_dict(state.params)
    if problem.config.formulation != "tracker":
        return transform_points(robot.fk_tool(q, params), point)
    return transform_points(state.tracker_pose @ robot.fk(q, params), state.tool_points[target_index])


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


def _projection_inputs(problem: Problem, state: State, params: np.ndarray | None) -> list:
    inputs = [] if params is None else [params]
    inputs.append(gtsam.Pose3(state.fixture_pose))
    if state.intrinsics is not None:
        inputs.append(np.asarray(state.intrinsics, dtype=float))
    return inputs


def _focal(problem: Problem, state: State) -> float:
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
        inputs = _projection_inputs(problem, state, None)
        pixels = np.linalg.norm(projections.compute(inputs, False).residual.reshape(-1, 2), axis=1)
        metric = pixels * projections.camera_points(inputs)[3][:, 2] / _focal(problem, state)
        return {"reprojection": metric, "reprojection_px": pixels}
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


def predicted_held_out(result, against_truth: bool) -> dict:
    """Predicted RMS (m) of exactly what the held-out score measures, for the held-out
    configurations: the parameter (and auxiliary unknown) uncertainty carried to the scored
    positions, with the score's gauge removed, plus, against held-out measurements, their
    noise (the declared sigma times the fit's sigma0). Returns the parts too.

    - tracker: reflector positions in the tracker frame, uncertain through P, the tracker pose
      and the tool points; against measurements, plus 3 sigma^2 per point;
    - pairs and projection against the truth: the scored point in W, the gauge (common offset
      or best rigid motion, as gauge_of says) removed; no noise (the truth is exact).
    """
    problem, config = result.problem, result.config
    q = problem.dataset.q[problem.test]
    if not len(q) or result.joint_covariance is None or not result.released:
        return {}
    factor = result.fit.variance_factor if result.fit is not None else 1.0
    model = BatchKinematics(problem.robot, result.state.params, result.released, q, problem.frame)
    p_values = model.base[model.index]
    if config.formulation == "tracker":
        rows = _held_out_tracker_rows(problem) if not against_truth else _all_targets(problem, len(q))
        if not rows:
            return {}
        points = TrackerPoints(
            model,
            P_KEY,
            TRACKER_KEY,
            TOOL_POINTS_KEY,
            len(result.state.tool_points),
            np.array([r[0] for r in rows]),
            np.array([r[1] for r in rows]),
            np.zeros((len(rows), 3)),
            config.tracker_sigma_m,
        )
        inputs = [p_values, gtsam.Pose3(result.state.tracker_pose), result.state.tool_points.reshape(-1)]
        J = np.hstack(points.compute(inputs, True).blocks).reshape(len(rows), 3, -1)
        covariance = result.joint_covariance.block([P_KEY, TRACKER_KEY, TOOL_POINTS_KEY])
        parameters = np.einsum("oij,jk,oik->o", J, covariance, J)
        noise = 0.0 if against_truth else 3.0 * factor * config.tracker_sigma_m**2
    elif not against_truth and config.formulation == "projection":
        projections = held_out_projections(problem, result.state, result.released)
        if projections is None:
            return {}
        inputs = _projection_inputs(problem, result.state, p_values)
        evaluation = projections.compute(inputs, True)
        J = np.hstack(evaluation.blocks).reshape(-1, 2, sum(d for _, _, d in projections.variables))
        keys = [key for key, _, _ in projections.variables]
        to_m = projections.camera_points(inputs)[3][:, 2] / _focal(problem, result.state)
        parameters = np.einsum("oij,jk,oik->o", J, result.joint_covariance.block(keys), J) * to_m**2
        noise = 2.0 * factor * config.pixel_sigma_px**2 * float(np.mean(to_m**2))
    elif not against_truth:
        if config.formulation != "pairs":
            return {}
        pairs = held_out_pairs(problem, result.state, result.released)
        if pairs is None:
            return {}
        J = pairs.compute([p_values], True).blocks[0].reshape(-1, 3, len(result.released))
        parameters = np.einsum("oij,jk,oik->o", J, result.covariance, J)
        noise = 3.0 * factor * config.camera_point_sigma_m**2
    else:
        data = kinematics.forward(problem.robot, result.state.params, q)
        J = kinematics.jacobian(problem.robot, data, result.released, frame="tool", point=result.tool_point)
        positions = transform_points(kinematics.frame_pose(problem.robot, data, "tool"), result.tool_point)
        flat = _without_gauge(J.reshape(-1, J.shape[2]), positions, gauge_of(problem))
        per_row = np.einsum("ij,jk,ik->i", flat, result.covariance, flat)
        parameters, noise = per_row.reshape(len(q), 3).sum(axis=1), 0.0
    return {
        "rms": float(np.sqrt(np.mean(parameters) + noise)),
        "parameters_rms": float(np.sqrt(np.mean(parameters))),
        "noise_rms": float(np.sqrt(noise)),
        "variance_factor": factor,
    }


def position_covariances(result) -> np.ndarray:
    """Covariance (N, 3, 3) of the scored point's error at each held-out configuration, with
    the score's gauge removed (camera formulations, scored against the truth), from the
    parameter covariance: what a 95 % position interval is drawn from."""
    problem = result.problem
    q = problem.dataset.q[problem.test]
    data = kinematics.forward(problem.robot, result.state.params, q)
    J = kinematics.jacobian(problem.robot, data, result.released, frame="tool", point=result.tool_point)
    positions = transform_points(kinematics.frame_pose(problem.robot, data, "tool"), result.tool_point)
    flat = _without_gauge(J.reshape(-1, J.shape[2]), positions, gauge_of(problem)).reshape(len(q), 3, -1)
    return np.einsum("nij,jk,nlk->nil", flat, result.covariance, flat)


def _without_gauge(J: np.ndarray, positions: np.ndarray, gauge: str) -> np.ndarray:
    """Rows (3N, m) of position Jacobians with the gauge's directions projected out: the
    common translation, or the infinitesimal rigid motions omega x (p - mean) + t."""
    if gauge == "none":
        return J
    n = len(positions)
    G = np.tile(np.eye(3), (n, 1))
    if gauge == "rigid":
        G = np.hstack([-skew(positions - positions.mean(axis=0)).reshape(-1, 3), G])
    Q, _ = np.linalg.qr(G)
    return J - Q @ (Q.T @ J)


def _held_out_tracker_rows(problem) -> list[tuple[int, int]]:
    """(held-out configuration index, target index) of each held-out tracker measurement."""
    table = problem.dataset.tables["tracker_points"]
    config_pos = {c: i for i, c in enumerate(problem.dataset.configs)}
    test_pos = {int(c): i for i, c in enumerate(problem.test)}
    target_index = {t: i for i, t in enumerate(problem.targets)}
    rows = [
        (test_pos[config_pos[cid]], target_index[name])
        for cid, name in zip(table.ids["config"], table.ids["target"], strict=True)
        if config_pos[cid] in test_pos and name in target_index
    ]
    return sorted(rows)


def _all_targets(problem, n_configs: int) -> list[tuple[int, int]]:
    return [(j, t) for j in range(n_configs) for t in range(len(problem.targets))]


def workspace_map(result) -> dict | None:
    """Where the robot was checked and how well it is known there: at each held-out
    configuration the scored point in W (m; for the tracker, the first reflector), its
    predicted sigma from the estimate's uncertainty (m, the score's gauge removed; no noise)
    and, where the score has one per point, the measured held-out error (m)."""
    problem, config = result.problem, result.config
    q = problem.dataset.q[problem.test]
    if not len(q) or not result.released or result.joint_covariance is None:
        return None
    if config.formulation != "tracker":
        data = kinematics.forward(problem.robot, result.state.params, q)
        positions = transform_points(kinematics.frame_pose(problem.robot, data, "tool"), result.tool_point)
        sigma = np.sqrt(np.trace(position_covariances(result), axis1=1, axis2=2))
        after = result.validation.get("after", {}).get("tool_point")
        measured = after.errors if after is not None and len(after.errors) == len(q) else None
        return {"positions_m": positions, "predicted_sigma_m": sigma, "measured_m": measured}
    rows = [row for row in _held_out_tracker_rows(problem) if row[1] == 0]  # one reflector says where
    if not rows:
        return None
    model = BatchKinematics(problem.robot, result.state.params, result.released, q, "flange")
    table = problem.dataset.tables["tracker_points"]
    measured_points = {
        (str(c), str(n)): xyz for c, n, xyz in zip(table.ids["config"], table.ids["target"], table.values, strict=True)
    }  # fmt: skip
    points = TrackerPoints(
        model, P_KEY, TRACKER_KEY, TOOL_POINTS_KEY, len(result.state.tool_points),
        np.array([r[0] for r in rows]), np.array([r[1] for r in rows]), np.zeros((len(rows), 3)),
        config.tracker_sigma_m,
    )  # fmt: skip
    inputs = [model.base[model.index], gtsam.Pose3(result.state.tracker_pose), result.state.tool_points.reshape(-1)]
    evaluation = points.compute(inputs, True)
    J = np.hstack(evaluation.blocks).reshape(len(rows), 3, -1)
    covariance = result.joint_covariance.block([P_KEY, TRACKER_KEY, TOOL_POINTS_KEY])
    predicted = evaluation.residual.reshape(-1, 3)  # the reflectors in the tracker frame
    ids = [str(problem.dataset.configs[problem.test[j]]) for j, _ in rows]
    measured = np.array(
        [
            np.linalg.norm(p - measured_points[(c, str(problem.targets[t]))])
            for p, c, (_, t) in zip(predicted, ids, rows, strict=True)
        ]
    )  # fmt: skip
    T_W_T = np.linalg.inv(result.state.tracker_pose)
    return {
        "positions_m": predicted @ T_W_T[:3, :3].T + T_W_T[:3, 3],
        "predicted_sigma_m": np.sqrt(np.einsum("oij,jk,oik->o", J, covariance, J)),
        "measured_m": measured,
    }
