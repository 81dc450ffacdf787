"""Scoring against a simulation's ground truth.

This is the only module of the calibration that reads ``truth/ground_truth.yaml``; it is
called after the estimate is final, to score it, and nothing it returns feeds back into
the estimation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..fields import read_yaml
from ..se3 import inverse, pose_from_xyz_rpy, transform_points


def load_truth(dataset_path: Path) -> dict | None:
    path = Path(dataset_path) / "truth" / "ground_truth.yaml"
    return read_yaml(path) if path.exists() else None


def _pose(doc: dict) -> np.ndarray:
    return pose_from_xyz_rpy(np.array(doc["xyz"], float), np.array(doc["rpy"], float))


def true_positions(problem, truth: dict, q: np.ndarray, point: np.ndarray | None, target: str | None) -> np.ndarray:
    """True positions (N, 3) of what is scored: for pairs, ``point`` fixed in the true
    camera frame, in W; for the tracker, the reflector ``target`` in the tracker frame."""
    robot = problem.robot
    params = truth["parameters"]
    if problem.config.formulation != "tracker":
        # The true tool.* perturbs the simulation's nominal mounting, which a dataset's (or a
        # user's) mounting guess need not equal.
        true_robot = robot.with_tool(_pose(truth["camera_mounting_nominal"]))
        return transform_points(true_robot.fk_tool(q, params), point)
    T_T_W = inverse(_pose(truth["tracker_pose"]))
    return transform_points(T_T_W @ robot.fk(q, params), np.array(truth["tracker_targets"][target], float))
