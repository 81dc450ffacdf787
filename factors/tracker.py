"""Factors of the classical formulation (SPEC section 4, eq. 1): an external tracker
measures points (3D), distances (1D) or poses (6D) of the tool."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import Evaluation, MeasurementSet, RobustLoss, point_jacobian, row_starts
from .kinematics import Kinematics, params_variable


class TrackerPoints(MeasurementSet):
    """``r_o = L (X(P, q_j) s_t) - m_o``  (m), per observed point o.

    Tool point s_t (flange or tool frame, whichever the kinematics give; all tool points are one
    vector S = (s_0, s_1, ...)) measured at m_o in the instrument's frame at configuration j,
    whose frame pose X comes from the kinematics; ``L = T_T_W``. L and S are variables (keys)
    or constants (``tracker``, 4x4; ``points``, (k, 3)): with L = I and m = 0 this is where a
    point fixed on the robot is in W, the model every score against a simulation's truth
    evaluates. The robust unit is one point.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        tracker_key: int | None,
        points_key: int | None,
        n_points: int,
        configs: np.ndarray,
        targets: np.ndarray,
        measured_m: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
        tracker: np.ndarray | None = None,
        points: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.configs = np.asarray(configs, dtype=int)
        self.targets = np.asarray(targets, dtype=int)
        self.measured = np.asarray(measured_m, dtype=float).reshape(-1, 3)
        if not len(self.configs) == len(self.targets) == len(self.measured) or not len(self.configs):
            raise ValueError("one configuration, target and point per observation, at least one")
        if (tracker_key is None) == (tracker is None) or (points_key is None) == (points is None):
            raise ValueError("the instrument pose and the tool points: each a variable key or a constant")
        self.n_points = int(n_points)
        self.tracker = None if tracker is None else np.asarray(tracker, dtype=float)
        self.points = None if points is None else np.asarray(points, dtype=float).reshape(-1, 3)
        self.variables = params_variable(params_key, kinematics)
        if tracker_key is not None:
            self.variables.append((tracker_key, "pose3", None))
        if points_key is not None:
            self.variables.append((points_key, "vector", 3 * self.n_points))
        self.sigma = np.full(3 * len(self.configs), float(sigma_m))
        self.unit_starts = row_starts([3] * len(self.configs))
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        inputs = list(inputs)
        params = inputs.pop(0) if self.params_key is not None else None
        T_L = inputs.pop(0).matrix() if self.tracker is None else self.tracker
        S = np.asarray(inputs.pop(0), dtype=float).reshape(-1, 3) if self.points is None else self.points
        s = S[self.targets]
        T_X = self.kinematics.poses(params)[self.configs]
        R_X, R_L = T_X[:, :3, :3], T_L[:3, :3]
        p_W = np.einsum("oij,oj->oi", R_X, s) + T_X[:, :3, 3]
        residual = (p_W @ R_L.T + T_L[:3, 3] - self.measured).reshape(-1)
        if not jacobians:
            return Evaluation(residual, [])
        blocks = []
        if params is not None:
            J = self.kinematics.jacobians(params)[self.configs]
            blocks.append(np.matmul(R_L @ point_jacobian(R_X, s), J).reshape(-1, J.shape[2]))
        if self.tracker is None:
            blocks.append(point_jacobian(R_L, p_W).reshape(-1, 6))
        if self.points is None:
            d_points = np.zeros((len(s), 3, 3 * self.n_points))
            rows = np.arange(len(s))
            for axis in range(3):
                d_points[rows, :, 3 * self.targets + axis] = (R_L @ R_X)[:, :, axis]
            blocks.append(d_points.reshape(-1, 3 * self.n_points))
        return Evaluation(residual, blocks)


class Distances(MeasurementSet):
    """``r_o = |X(P, q_j) s - e_o| - d_o``  (m), per reading o, where the other
    end ``e_o`` is a fixed pivot ``a_k`` or the same tool point at another configuration,
    ``X(P, q_b) s``.

    A ballbar (or any 1D gauge) between the tool point s (flange frame, a 3-vector variable)
    and the fixed pivot k, whose position a_k in W is unknown (all pivots are one vector
    variable A = (a_0, a_1, ...)), or a gauge between two positions of the tool point (a
    two-ball bar, an interferometer's travel), reads d_o at configuration j. ``pivots[o]`` is
    -1 for a reading between configurations, ``others[o]`` -1 for a reading to a pivot; with
    no pivot at all, there is no pivot variable. The robust unit is one reading.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        tool_point_key: int,
        pivots_key: int | None,
        n_pivots: int,
        configs: np.ndarray,
        pivots: np.ndarray,
        distances_m: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
        others: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.configs = np.asarray(configs, dtype=int)
        self.pivots = np.asarray(pivots, dtype=int)
        self.others = np.full(len(self.configs), -1) if others is None else np.asarray(others, dtype=int)
        self.distances = np.asarray(distances_m, dtype=float).reshape(-1)
        if not len(self.configs) == len(self.pivots) == len(self.others) == len(self.distances) or not len(
            self.configs
        ):
            raise ValueError("one configuration, pivot or other configuration, and distance per reading")
        if np.any((self.pivots >= 0) == (self.others >= 0)):
            raise ValueError("each reading is to a pivot or to another configuration, not both or neither")
        self.n_pivots = int(n_pivots)
        if (self.n_pivots > 0) != (pivots_key is not None):
            raise ValueError("a pivot variable exactly when there are pivots")
        self.variables = [*params_variable(params_key, kinematics), (tool_point_key, "vector", 3)]
        if pivots_key is not None:
            self.variables.append((pivots_key, "vector", 3 * self.n_pivots))
        self.sigma = np.full(len(self.configs), float(sigma_m))
        self.unit_starts = np.arange(len(self.configs))
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        params = inputs[0] if self.params_key is not None else None
        s = np.asarray(inputs[1 if params is not None else 0], dtype=float)
        to_pivot, to_other = self.pivots >= 0, self.others >= 0
        T_all = self.kinematics.poses(params)
        T_X, T_B = T_all[self.configs], T_all[np.maximum(self.others, 0)]
        R_X, R_B = T_X[:, :3, :3], T_B[:, :3, :3]
        end = np.zeros((len(self.configs), 3))
        if self.n_pivots:
            pivots = np.asarray(inputs[-1], dtype=float).reshape(-1, 3)
            end[to_pivot] = pivots[self.pivots[to_pivot]]
        end[to_other] = R_B[to_other] @ s + T_B[to_other, :3, 3]
        delta = R_X @ s + T_X[:, :3, 3] - end
        length = np.linalg.norm(delta, axis=1)
        residual = length - self.distances
        if not jacobians:
            return Evaluation(residual, [])
        unit = delta / np.maximum(length, 1e-300)[:, None]
        blocks = []
        if params is not None:
            J = self.kinematics.jacobians(params)
            ones = np.broadcast_to(s, (len(R_X), 3))
            d_xi = np.einsum("oi,oij->oj", unit, point_jacobian(R_X, ones))
            d_params = np.einsum("oj,ojm->om", d_xi, J[self.configs])
            d_xi_other = np.einsum("oi,oij->oj", unit, point_jacobian(R_B, ones))
            d_params[to_other] -= np.einsum("oj,ojm->om", d_xi_other, J[np.maximum(self.others, 0)])[to_other]
            blocks.append(d_params)
        d_s = np.einsum("oi,oij->oj", unit, R_X)
        d_s[to_other] -= np.einsum("oi,oij->oj", unit, R_B)[to_other]
        blocks.append(d_s)
        if self.n_pivots:
            d_pivots = np.zeros((len(self.configs), 3 * self.n_pivots))
            rows = np.flatnonzero(to_pivot)
            for axis in range(3):
                d_pivots[rows, 3 * self.pivots[rows] + axis] = -unit[rows, axis]
            blocks.append(d_pivots)
        return Evaluation(residual, blocks)


class Poses(MeasurementSet):
    """``r_o = Log(Z_o^-1 L X(P, q_j) E)``  (rad, m), per measured pose o.

    Measured pose Z_o of a tool frame in the tracker frame (a 6D probe, or a camera's pose of
    a target); L = T_T_W and E = T_n_tool are Pose3 variables. Rotation and translation rows
    have their own sigmas; the robust unit is the pose.
    """

    def row_units(self) -> dict[str, np.ndarray]:
        rotation = np.tile([True] * 3 + [False] * 3, len(self.configs))
        return {"rad": rotation, "m": ~rotation}

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        tracker_key: int,
        tool_key: int,
        configs: np.ndarray,
        measured: list[np.ndarray],
        sigma_rad: float,
        sigma_m: float,
        robust: RobustLoss | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.configs = np.asarray(configs, dtype=int)
        if len(self.configs) != len(measured) or not len(self.configs):
            raise ValueError("one configuration per measured pose, at least one")
        self.measured_inverse = [gtsam.Pose3(np.asarray(Z, dtype=float)).inverse() for Z in measured]
        self.variables = [
            *params_variable(params_key, kinematics),
            (tracker_key, "pose3", None),
            (tool_key, "pose3", None),
        ]
        self.sigma = np.tile([sigma_rad] * 3 + [sigma_m] * 3, len(self.configs)).astype(float)
        self.unit_starts = row_starts([6] * len(self.configs))
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        params = inputs[0] if self.params_key is not None else None
        tracker, tool = inputs[-2], inputs[-1]
        T_X = self.kinematics.poses(params)[self.configs]
        J = self.kinematics.jacobians(params)[self.configs] if jacobians and params is not None else None
        residual, d_params, d_tracker, d_tool = [], [], [], []
        log_jacobian = np.zeros((6, 6), order="F")
        for o, (Z_inv, T) in enumerate(zip(self.measured_inverse, T_X, strict=True)):
            pose = gtsam.Pose3(T)
            error_pose = Z_inv.compose(tracker).compose(pose).compose(tool)
            if not jacobians:
                residual.append(gtsam.Pose3.Logmap(error_pose))
                continue
            residual.append(gtsam.Pose3.Logmap(error_pose, log_jacobian))
            # A right perturbation of L, X or E moves L X E by the adjoint of what follows it.
            d_tracker.append(log_jacobian @ pose.compose(tool).inverse().AdjointMap())
            d_pose = log_jacobian @ tool.inverse().AdjointMap()
            if J is not None:
                d_params.append(d_pose @ J[o])
            d_tool.append(log_jacobian.copy())
        if not jacobians:
            return Evaluation(np.concatenate(residual), [])
        blocks = [np.vstack(d_params)] if J is not None else []
        blocks += [np.vstack(d_tracker), np.vstack(d_tool)]
        return Evaluation(np.concatenate(residual), blocks)
