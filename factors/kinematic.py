"""Kinematic factor: ties the parameter vector to one configuration's pose variable."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import CheckedFactor, gaussian


class KinematicFactor(CheckedFactor):
    """``r = Log(FK(P, q_j)^-1 X_j)``  (rad, m; GTSAM order [omega, v]).

    ``P`` is the vector of released parameters, ``X_j`` the pose variable (camera or flange
    in W) of configuration j. ``model`` is a :class:`fgcal.calibration.batch.BatchKinematics`
    shared by all kinematic factors of a graph: it evaluates FK and its body Jacobian for
    every configuration at once and caches them on P, so one linearisation costs one
    vectorised kinematics pass.
    """

    def __init__(self, params_key: int, pose_key: int, j: int, model, sigmas: np.ndarray) -> None:
        self.model = model
        self.j = j
        super().__init__(
            [(params_key, "vector", model.n_released), (pose_key, "pose3", None)], gaussian(sigmas), sigmas
        )

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        params, pose = inputs
        fk = gtsam.Pose3(self.model.poses(params)[self.j])
        between = fk.inverse().compose(pose)
        if not jacobians:
            return gtsam.Pose3.Logmap(between), []
        log_jacobian = np.zeros((6, 6), order="F")
        residual = gtsam.Pose3.Logmap(between, log_jacobian)
        # FK Exp(d) changes the between pose by Exp(-Ad(between^-1) d) on the right.
        d_fk = -log_jacobian @ between.inverse().AdjointMap()
        return residual, [d_fk @ self.model.jacobians(params)[self.j], log_jacobian]
