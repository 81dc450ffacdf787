"""Scoring against a simulation's ground truth.

This is the only module of the calibration that reads ``truth/ground_truth.yaml``; it is
called after the calibration (``score_with_truth(result)``), and nothing it returns feeds
back into the estimation. The truth is evaluated with the simulator's own full model, not the
model that was fitted: a DH fit of a compliant robot is scored against the compliant robot.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..fields import read_yaml
from ..se3 import inverse, pose_from_xyz_rpy, transform_points
from .prediction import position_covariances
from .run import CalibrationResult
from .state import State
from .validation import gauge_of, predicted_positions, remove_gauge, stats


def load_truth(dataset_path: Path) -> dict | None:
    path = Path(dataset_path) / "truth" / "ground_truth.yaml"
    return read_yaml(path) if path.exists() else None


def _pose(doc: dict) -> np.ndarray:
    return pose_from_xyz_rpy(np.array(doc["xyz"], float), np.array(doc["rpy"], float))


def true_positions(problem, truth: dict, q: np.ndarray, point: np.ndarray | None, target: str | None) -> np.ndarray:
    """True positions (N, 3) of what is scored: for pairs, ``point`` fixed in the true
    camera frame, in W; for the tracker, the reflector ``target`` in the tracker frame; for
    touches and ballbars, the true probe (ball) in W; for 6D poses, the origin of the true
    probe's frame in the true tracker's frame; for a static camera, the true board's origin in W."""
    robot = problem.dataset.robot.with_model(truth.get("model", "DH,s,e"))
    params = truth["parameters"]
    formulation = problem.config.formulation
    if formulation == "touch":  # the true probe, whatever the estimate
        return transform_points(robot.fk(q, params), np.array(truth["touch_probe"], float))
    if formulation == "distances":
        return transform_points(robot.fk(q, params), np.array(truth["ballbar"]["ball"], float))
    if formulation == "poses":  # the true probe's origin, in the true tracker's frame
        T_T_W = inverse(_pose(truth["tracker_pose"]))
        return transform_points(T_T_W @ robot.fk(q, params), _pose(truth["tracker_probe"])[:3, 3])
    if formulation == "static_camera":  # the true board's origin, in W
        return transform_points(robot.fk(q, params), _pose(truth["static_camera"]["board_mount"])[:3, 3])
    if problem.config.formulation != "tracker":
        # The true tool.* perturbs the simulation's nominal mounting, which a dataset's (or a
        # user's) mounting guess need not equal.
        true_robot = robot.with_tool(_pose(truth["camera_mounting_nominal"]))
        return transform_points(true_robot.fk_tool(q, params), point)
    T_T_W = inverse(_pose(truth["tracker_pose"]))
    return transform_points(T_T_W @ robot.fk(q, params), np.array(truth["tracker_targets"][target], float))


def truth_errors(
    problem, state: State, truth: dict, point: np.ndarray, q: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """Error vectors (N, 3) (m) on the held-out configurations (or at ``q``, e.g. independent
    ones) against the truth, per scored point.

    Pairs and projection: ``point`` (in the camera frame) and the camera origin, in W, after
    removing the gauge (fgcal.calibration.validation.gauge_of); tracker: the reflectors in the
    tracker frame, no gauge."""
    q = problem.dataset.q[problem.test] if q is None else q
    if not len(q):  # nothing held out: nothing to score
        return {}
    if problem.config.formulation != "tracker":
        out = {}
        labels = (("tool_point", point), ("camera_origin", np.zeros(3)))
        for label, p in labels if problem.config.formulation in ("pairs", "projection") else labels[:1]:
            residual = remove_gauge(
                predicted_positions(problem, state, q, p, None),
                true_positions(problem, truth, q, p, None),
                gauge_of(problem),
            )
            out[label] = residual
        return out
    errors = [
        predicted_positions(problem, state, q, None, t) - true_positions(problem, truth, q, None, target)
        for t, target in enumerate(problem.targets)
    ]
    return {"tool_point": np.concatenate(errors)}


def score_with_truth(result: CalibrationResult) -> bool:
    """Score a finished calibration against its simulation's truth, if the dataset has one:
    the before/after held-out errors are then those against the truth, and the report shows
    the true parameters. Returns whether there was a truth."""
    truth = load_truth(result.problem.dataset.path)
    if truth is None:
        return False
    validation = result.config.validation_dataset
    if validation is not None:
        # A validation set is scored against the truth only when it measured the same true robot.
        other = load_truth(validation)
        if other is None or other["parameters"] != truth["parameters"]:
            return False
    result.truth = truth
    for label, state in (("before", result.before), ("after", result.state)):
        errors = truth_errors(result.problem, state, truth, result.tool_point)
        result.validation[label] = {k: stats(v) for k, v in errors.items()}
    return True


CHI2_3_95 = 7.814727903251178  # 95 % quantile of chi-square with 3 degrees of freedom


def position_coverage(result: CalibrationResult) -> float:
    """Fraction of the held-out configurations whose true error (the scored point, gauge
    removed: truth_errors) lies inside the 95 % ellipsoid of its predicted covariance; camera
    formulations, needs the truth."""
    problem = result.problem
    truth = result.truth if result.truth is not None else load_truth(problem.dataset.path)
    error = truth_errors(problem, result.state, truth, result.tool_point)["tool_point"]
    covariances = position_covariances(result)
    # Pseudo-inverse: removing the gauge leaves each 3x3 block full rank here, but not by design.
    d2 = np.einsum("ni,nij,nj->n", error, np.linalg.pinv(covariances), error)
    return float(np.mean(d2 <= CHI2_3_95))


def compensation_study(result: CalibrationResult, n_targets: int = 200, seed: int = 0) -> dict:
    """Compensation scored on the simulated true robot (fgcal.compensate): ``n_targets``
    random TCP positions in the calibrated region (the scored point at the dataset's
    configurations moved by up to 0.1 rad per joint, seeded), each from a hint 0.05 rad off.
    Compensated: the joints at which the calibrated model reaches the target; uncompensated:
    the joints the controller's nominal model finds for it. Both are driven through the true
    robot; the score's gauge (gauge_of) is removed from both error sets, as the held-out
    score removes it (SI)."""
    from ..compensate import compensate, nominal_of

    problem = result.problem
    truth = result.truth if result.truth is not None else load_truth(problem.dataset.path)
    robot = problem.robot  # build_problem gave it the result's model
    params = robot.parameter_dict(result.state.params)
    rng = np.random.default_rng(seed)
    q_data = problem.dataset.q[rng.integers(0, len(problem.dataset.q), n_targets)]
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q_target = np.clip(q_data + rng.uniform(-0.1, 0.1, q_data.shape), low, high)
    tcp = result.tool_point
    targets = transform_points(robot.fk_tool(q_target, params), tcp)
    hints = np.clip(q_target + rng.normal(0.0, 0.05, q_target.shape), low, high)
    nominal = nominal_of(problem.dataset.robot, None)
    solved = compensate(replace(robot, overrides=params), nominal, targets, hints, tcp)
    controller = nominal.ik(targets, hints, tcp=tcp)
    usable = np.isin(solved.status, ("ok", "near singularity")) & np.isin(controller.status, ("ok", "near singularity"))
    gauge = gauge_of(problem)
    compensated = remove_gauge(true_positions(problem, truth, solved.q[usable], tcp, None), targets[usable], gauge)
    uncompensated = remove_gauge(
        true_positions(problem, truth, controller.q[usable], tcp, None), targets[usable], gauge
    )
    compensated_rms, uncompensated_rms = stats(compensated).rms, stats(uncompensated).rms
    return {
        "n_targets": int(n_targets),
        "n_scored": int(usable.sum()),
        "status": {s: int(np.sum(solved.status == s)) for s in sorted(set(solved.status.tolist()))},
        "model_residual_max_m": float(solved.residual_m[usable].max()),
        "compensated_rms_m": compensated_rms,
        "uncompensated_rms_m": uncompensated_rms,
        "improvement": uncompensated_rms / compensated_rms,
        "gauge_removed": gauge,
        "seed": seed,
    }
