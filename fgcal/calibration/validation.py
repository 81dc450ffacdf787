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

import numpy as np

from ..se3 import kabsch, transform_points
from .problem import Problem
from .state import State


@dataclass
class ErrorStats:
    mean: float
    rms: float
    max: float
    errors: np.ndarray

    def as_dict(self) -> dict:
        return {"mean": self.mean, "rms": self.rms, "max": self.max}


def stats(errors: np.ndarray) -> ErrorStats:
    errors = np.asarray(errors, dtype=float)
    if errors.size == 0:
        return ErrorStats(float("nan"), float("nan"), float("nan"), errors)
    return ErrorStats(float(errors.mean()), float(np.sqrt(np.mean(errors**2))), float(errors.max()), errors)


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


def held_out_errors(problem: Problem, state: State) -> dict[str, np.ndarray]:
    """Error norms (m) on the held-out configurations against their measurements, per scored
    point: the tracker's reflectors. (Scores against a simulation's truth: fgcal.calibration.scoring.)"""
    data = problem.dataset
    if problem.config.formulation != "tracker":
        return {}
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
            errors.append(np.linalg.norm(predicted - np.array([xyz for _, xyz in rows]), axis=1))
    return {"tool_point": np.concatenate(errors) if errors else np.zeros(0)}
