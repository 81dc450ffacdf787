"""Factors of the classical formulation (SPEC section 4, eq. 1): an external tracker
measures a point (3D), a distance (1D) or a pose (6D) of the tool."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import CheckedFactor, point_jacobian


class TrackerPointFactor(CheckedFactor):
    """``r = L (X_j s) - m``  (m): tool point s (flange frame, Point3 variable) seen at
    configuration j (flange pose X_j in W) by a tracker at pose ``L = T_T_W`` (Pose3 variable)."""

    def __init__(
        self,
        tracker_key: int,
        pose_key: int,
        point_key: int,
        measured: np.ndarray,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
    ) -> None:
        self.measured = np.asarray(measured, dtype=float)
        super().__init__(
            [(tracker_key, "pose3", None), (pose_key, "pose3", None), (point_key, "point3", None)], noise, sigmas
        )

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        tracker, pose, point = inputs
        T_L, T_X = tracker.matrix(), pose.matrix()
        s = np.asarray(point, dtype=float)
        p_W = T_X[:3, :3] @ s + T_X[:3, 3]
        residual = T_L[:3, :3] @ p_W + T_L[:3, 3] - self.measured
        if not jacobians:
            return residual, []
        R_L = T_L[:3, :3]
        return residual, [point_jacobian(R_L, p_W), R_L @ point_jacobian(T_X[:3, :3], s), R_L @ T_X[:3, :3]]


class DistanceFactor(CheckedFactor):
    """``r = |X_j s - a| - d``  (m): measured distance d from an anchor point a (Point3
    variable, in W) to the tool point s (Point3 variable, flange frame)."""

    def __init__(
        self,
        anchor_key: int,
        pose_key: int,
        point_key: int,
        distance: float,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
    ) -> None:
        self.distance = float(distance)
        super().__init__(
            [(anchor_key, "point3", None), (pose_key, "pose3", None), (point_key, "point3", None)], noise, sigmas
        )

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        anchor, pose, point = inputs
        T_X = pose.matrix()
        s = np.asarray(point, dtype=float)
        delta = T_X[:3, :3] @ s + T_X[:3, 3] - np.asarray(anchor, dtype=float)
        length = float(np.linalg.norm(delta))
        residual = np.array([length - self.distance])
        if not jacobians:
            return residual, []
        unit = (delta / length)[None, :]
        return residual, [-unit, unit @ point_jacobian(T_X[:3, :3], s), unit @ T_X[:3, :3]]


class PoseFactor(CheckedFactor):
    """``r = Log(Z^-1 L X_j E)``  (rad, m): measured pose Z of a tool frame in the tracker
    frame; L = T_T_W (Pose3 variable), X_j the flange pose, E = T_n_tool (Pose3 variable)."""

    def __init__(
        self,
        tracker_key: int,
        pose_key: int,
        tool_key: int,
        measured: gtsam.Pose3,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
    ) -> None:
        self.measured_inverse = measured.inverse()
        super().__init__(
            [(tracker_key, "pose3", None), (pose_key, "pose3", None), (tool_key, "pose3", None)], noise, sigmas
        )

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        tracker, pose, tool = inputs
        error_pose = self.measured_inverse.compose(tracker).compose(pose).compose(tool)
        if not jacobians:
            return gtsam.Pose3.Logmap(error_pose), []
        log_jacobian = np.zeros((6, 6), order="F")
        residual = gtsam.Pose3.Logmap(error_pose, log_jacobian)
        # A right perturbation of L, X or E moves L X E by the adjoint of what follows it.
        after_tracker = pose.compose(tool).inverse().AdjointMap()
        after_pose = tool.inverse().AdjointMap()
        return residual, [log_jacobian @ after_tracker, log_jacobian @ after_pose, log_jacobian]
