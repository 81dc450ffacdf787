"""Factors of touch-point self-calibration: a ball or probe on the tool sits in fixed sockets
(pins, spheres, cones) at many configurations. No instrument measures anything: the chain
closes because every touch of a socket puts the tool point at the same unknown place, the
mechanical twin of the camera's relative point pairs."""

from __future__ import annotations

import numpy as np

from .base import Evaluation, MeasurementSet, RobustLoss, point_jacobian
from .kinematics import Kinematics, params_variable


class TouchPoints(MeasurementSet):
    """``r_o = X(P, q_j) s - a_k``  (m), per touch o.

    At configuration j the tool point s (flange frame, a 3-vector variable) sits in socket k,
    whose position a_k in W is unknown (all sockets are one vector variable A = (a_0, a_1, ...));
    X is the flange pose from the kinematics. The robust unit is one touch.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        tool_point_key: int,
        sockets_key: int,
        n_sockets: int,
        configs: np.ndarray,
        sockets: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.configs = np.asarray(configs, dtype=int)
        self.sockets = np.asarray(sockets, dtype=int)
        if len(self.configs) != len(self.sockets) or not len(self.configs):
            raise ValueError("one configuration per touch, at least one")
        self.n_sockets = int(n_sockets)
        self.variables = [
            *params_variable(params_key, kinematics),
            (tool_point_key, "vector", 3),
            (sockets_key, "vector", 3 * self.n_sockets),
        ]
        self.sigma = np.full(3 * len(self.configs), float(sigma_m))
        self.unit_starts = 3 * np.arange(len(self.configs))
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        params = inputs[0] if self.params_key is not None else None
        s = np.asarray(inputs[-2], dtype=float)
        sockets = np.asarray(inputs[-1], dtype=float).reshape(-1, 3)
        T_X = self.kinematics.poses(params)[self.configs]
        R_X = T_X[:, :3, :3]
        residual = (R_X @ s + T_X[:, :3, 3] - sockets[self.sockets]).reshape(-1)
        if not jacobians:
            return Evaluation(residual, [])
        blocks = []
        if params is not None:
            J = self.kinematics.jacobians(params)[self.configs]
            blocks.append(np.matmul(point_jacobian(R_X, np.broadcast_to(s, (len(R_X), 3))), J).reshape(-1, J.shape[2]))
        blocks.append(R_X.reshape(-1, 3))
        d_sockets = np.zeros((len(self.configs), 3, 3 * self.n_sockets))
        rows = np.arange(len(self.configs))
        for axis in range(3):
            d_sockets[rows, axis, 3 * self.sockets + axis] = -1.0
        blocks.append(d_sockets.reshape(-1, 3 * self.n_sockets))
        return Evaluation(residual, blocks)


class SocketSpacings(MeasurementSet):
    """``r_o = |a_k - a_l| - d_o``  (m), per known distance o.

    The distance d_o between sockets k and l, from the fixture's drawing or a measurement:
    what gives touch-point calibration its scale (without one, every length can grow by the
    same factor and the touches agree just as well).
    """

    def __init__(
        self,
        sockets_key: int,
        n_sockets: int,
        pairs: np.ndarray,
        distances_m: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
    ) -> None:
        self.pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
        self.distances = np.asarray(distances_m, dtype=float).reshape(-1)
        if len(self.pairs) != len(self.distances) or not len(self.pairs):
            raise ValueError("one pair of sockets per distance, at least one")
        if np.any(self.pairs[:, 0] == self.pairs[:, 1]):
            raise ValueError("a distance joins two different sockets")
        self.n_sockets = int(n_sockets)
        self.variables = [(sockets_key, "vector", 3 * self.n_sockets)]
        self.sigma = np.full(len(self.pairs), float(sigma_m))
        self.unit_starts = np.arange(len(self.pairs))
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        sockets = np.asarray(inputs[0], dtype=float).reshape(-1, 3)
        delta = sockets[self.pairs[:, 0]] - sockets[self.pairs[:, 1]]
        length = np.linalg.norm(delta, axis=1)
        residual = length - self.distances
        if not jacobians:
            return Evaluation(residual, [])
        unit = delta / np.maximum(length, 1e-300)[:, None]
        block = np.zeros((len(self.pairs), 3 * self.n_sockets))
        rows = np.arange(len(self.pairs))
        for axis in range(3):
            block[rows, 3 * self.pairs[:, 0] + axis] += unit[:, axis]
            block[rows, 3 * self.pairs[:, 1] + axis] -= unit[:, axis]
        return Evaluation(residual, [block])
