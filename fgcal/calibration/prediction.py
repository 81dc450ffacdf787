"""What the held-out scores should be: the estimate's uncertainty (the joint covariance of the
parameters and auxiliary unknowns) carried to exactly what each score measures, with the
score's gauge removed, plus the measurement noise where the score is against measurements;
and where in the workspace the robot is known how well."""

from __future__ import annotations

import gtsam
import numpy as np

from .. import kinematics
from ..factors import TrackerPoints, point_jacobian
from ..se3 import skew, transform_points
from .batch import BatchKinematics
from .graph import P_KEY, TOOL_POINTS_KEY, TOOL_POSE_KEY, TRACKER_KEY
from .validation import (
    CHAIN_FORMULATIONS,
    FIXED_POINT_FORMULATIONS,
    back_projections,
    declared_test_point,
    focal_px,
    gauge_of,
    held_out_measurements,
    held_out_pairs,
    held_out_projections,
    held_out_target,
    projection_inputs,
)


def predicted_held_out(result, against_truth: bool) -> dict:
    """Predicted RMS (m) of exactly what the held-out score measures, for the held-out
    configurations: the parameter (and auxiliary unknown) uncertainty carried to the scored
    positions, with the score's gauge removed, plus, against held-out measurements, their
    noise (the declared sigma times the fit's sigma0). Returns the parts too.

    - tracker: reflector positions in the tracker frame, uncertain through P, the tracker pose
      and the tool points; against measurements, plus 3 sigma^2 per point;
    - pairs and projection against the truth: the scored point in W, the gauge (common offset
      or best rigid motion, as gauge_of says) removed; no noise (the truth is exact);
    - touch against held-out touches: the probe's distance from the touched point, through P,
      the probe and the touched points, plus 3 sigma^2 per touch;
    - distances against held-out readings: through P, the ball and the pivots, plus sigma^2;
    - touch and distances against the truth: the probe (ball) in W, through P and the probe,
      the rigid gauge removed;
    - poses against held-out poses: the probe origin in the tracker frame, through P, the
      tracker pose and the probe frame, plus 3 sigma_m^2; against the truth the same, no noise;
    - static camera against held-out pixels: as projection, through P, the camera pose and the
      board mounting; against the truth the board origin in the camera frame, no noise;
    - pairs against held-out point pairs: through P (an estimated fixture rotation's own
      uncertainty is left out), plus 3 sigma^2 per contrast;
    - projection against held-out pixels: through P, the fixture pose (and the intrinsics when
      estimated), in the object's plane, plus 2 sigma_px^2 there.
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
        parameters, noise = np.zeros(0), np.zeros(0)
        if rows:
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
            noise = np.full(len(rows), 0.0 if against_truth else 3.0 * factor * config.tracker_sigma_m**2)
        if not against_truth:
            for more, more_noise in _test_point_rows(result, model, p_values, factor):
                parameters, noise = np.concatenate([parameters, more]), np.concatenate([noise, more_noise])
        if not len(parameters):
            return {}
        noise = float(np.mean(noise))
    elif not against_truth and config.formulation in (*FIXED_POINT_FORMULATIONS, *CHAIN_FORMULATIONS):
        held_out = held_out_measurements(problem, result.state, result.released)
        if held_out is None:
            return {}
        parameters, noise = _held_out_prediction(problem, result, held_out, p_values, factor)
    elif not against_truth and config.formulation == "projection":
        projections = held_out_projections(problem, result.state, result.released)
        if projections is None:
            return {}
        inputs = projection_inputs(problem, result.state, p_values)
        evaluation = projections.compute(inputs, True)
        J = np.hstack(evaluation.blocks).reshape(-1, 2, sum(d for _, _, d in projections.variables))
        keys = [key for key, _, _ in projections.variables]
        to_m = projections.camera_points(inputs)[3][:, 2] / focal_px(problem, result.state)
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
        parameters, noise = np.trace(position_covariances(result), axis1=1, axis2=2), 0.0
    return {
        "rms": float(np.sqrt(np.mean(parameters) + noise)),
        "parameters_rms": float(np.sqrt(np.mean(parameters))),
        "noise_rms": float(np.sqrt(noise)),
        "variance_factor": factor,
    }


def _held_out_prediction(problem, result, held_out, p_values: np.ndarray, factor: float) -> tuple[np.ndarray, float]:
    """Per held-out unit, the variance its score takes from the estimate (the set's Jacobian
    through the joint covariance of its variables), and the noise variance of the score."""
    config = problem.config
    measurements, aux = held_out
    inputs = [p_values, *aux]
    width = sum(d for _, _, d in measurements.variables)
    J = np.hstack(measurements.compute(inputs, True).blocks)
    covariance = result.joint_covariance.block([key for key, _, _ in measurements.variables])
    if config.formulation == "touch":
        return _through(J.reshape(-1, 3, width), covariance), 3.0 * factor * config.touch_sigma_m**2
    if config.formulation == "distances":
        return _through(J.reshape(-1, 1, width), covariance), factor * config.distance_sigma_m**2
    if config.formulation == "poses":  # the position rows of each pose's Log
        return _through(J.reshape(-1, 6, width)[:, 3:], covariance), 3.0 * factor * config.pose_sigma_m**2
    to_m = measurements.camera_points(inputs)[3][:, 2] / focal_px(problem, result.state)
    parameters = _through(J.reshape(-1, 2, width), covariance) * to_m**2
    return parameters, 2.0 * factor * config.pixel_sigma_px**2 * float(np.mean(to_m**2))


def _through(J: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Trace of J C J^T per unit: J (n, k, m), C (m, m)."""
    return np.einsum("oij,jk,oik->o", J, covariance, J)


def position_covariances(result) -> np.ndarray:
    """Covariance (N, 3, 3) of the scored point's error at each held-out configuration, with
    the score's gauge removed (camera formulations, scored against the truth), from the
    parameter covariance: what a 95 % position interval is drawn from."""
    problem = result.problem
    q = problem.dataset.q[problem.test]
    data = kinematics.forward(problem.robot, result.state.params, q)
    frame = problem.frame
    J = kinematics.jacobian(problem.robot, data, result.released, frame=frame, point=result.tool_point)
    pose = kinematics.frame_pose(problem.robot, data, frame)
    positions = transform_points(pose, result.tool_point)
    covariance = result.covariance
    formulation = problem.config.formulation
    if formulation in FIXED_POINT_FORMULATIONS:  # the probe is estimated too: d(X s)/ds = R_X
        J = np.concatenate([J, pose[:, :3, :3]], axis=2)
        covariance = result.joint_covariance.block([P_KEY, TOOL_POINTS_KEY])
    if formulation in CHAIN_FORMULATIONS:
        # E's origin e moves with E's translation: d(X e)/dE = R_X R_E [0, I].
        T_E = result.state.tool_pose
        d_tool = np.concatenate([np.zeros((len(q), 3, 3)), pose[:, :3, :3] @ T_E[:3, :3]], axis=2)
        J = np.concatenate([J, d_tool], axis=2)
        covariance = result.joint_covariance.block([P_KEY, TOOL_POSE_KEY])
    if formulation == "poses":
        # Scored in the tracker's frame, L X e: through L as well, everything turned by R_L.
        T_L = result.state.tracker_pose
        d_tracker = point_jacobian(T_L[:3, :3], positions)
        positions = transform_points(T_L, positions)
        J = np.concatenate([T_L[:3, :3] @ J, np.broadcast_to(d_tracker, (len(q), 3, 6))], axis=2)
        covariance = result.joint_covariance.block([P_KEY, TOOL_POSE_KEY, TRACKER_KEY])
    flat = without_gauge(J.reshape(-1, J.shape[2]), positions, gauge_of(problem)).reshape(len(q), 3, -1)
    return np.einsum("nij,jk,nlk->nil", flat, covariance, flat)


def without_gauge(J: np.ndarray, positions: np.ndarray, gauge: str) -> np.ndarray:
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


def _test_point_rows(result, model: BatchKinematics, p_values: np.ndarray, factor: float):
    """Per test point of a validation set (a tracker target the fit never saw), the variance
    each of its held-out errors takes from P and the tracker pose, and its noise variance, for
    the score of fgcal.calibration.validation.test_point_errors. Declared: the error's
    Jacobian A_j at the declared point. Leave-one-out: ``A_j - R_j mean_{i != j}(R_i^T A_i)``
    (the refitted point follows the others), and the noise 3 sigma^2 (1 + 1/(n - 1))."""
    problem, config = result.problem, result.config
    T_X, J_P = model.poses(p_values), model.jacobians(p_values)
    T_L = result.state.tracker_pose
    covariance = result.joint_covariance.block([P_KEY, TRACKER_KEY])
    sigma2 = 3.0 * factor * config.tracker_sigma_m**2
    for target in sorted(
        {str(n) for n in problem.dataset.tables["tracker_points"].ids["target"]} - set(problem.targets)
    ):
        at, measured = held_out_target(problem, target)
        if not len(at):
            continue
        declared = declared_test_point(problem, result.state, target)
        # Where the point is on the flange: declared, or as the measurements put it (for A_j only).
        s = declared if declared is not None else back_projections(T_L @ T_X[at], measured).mean(axis=0)
        R_X = T_X[at, :3, :3]
        p_W = np.einsum("oij,j->oi", R_X, s) + T_X[at, :3, 3]
        A = np.concatenate(
            [T_L[:3, :3] @ point_jacobian(R_X, np.broadcast_to(s, (len(at), 3))) @ J_P[at],
             np.broadcast_to(point_jacobian(T_L[:3, :3], p_W), (len(at), 3, 6))],
            axis=2,
        )  # fmt: skip
        if declared is not None:
            yield np.einsum("oij,jk,oik->o", A, covariance, A), np.full(len(at), sigma2)
            continue
        R = T_L[:3, :3] @ R_X
        back = np.einsum("oji,ojk->oik", R, A)  # R_i^T A_i
        loo = A - np.einsum("oij,ojk->oik", R, (back.sum(axis=0) - back) / (len(at) - 1))
        yield np.einsum("oij,jk,oik->o", loo, covariance, loo), np.full(len(at), sigma2 * (1 + 1 / (len(at) - 1)))


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
        positions = transform_points(kinematics.frame_pose(problem.robot, data, problem.frame), result.tool_point)
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
