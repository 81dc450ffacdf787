"""Kinematics of a growing set of configurations, for the online kinematic factors."""

from __future__ import annotations

import numpy as np

from .. import kinematics
from ..robot import Robot


class _Row:
    """``model.poses(P)[j]`` / ``model.jacobians(P)[j]`` without computing every row."""

    def __init__(self, model: GrowingKinematics, values: np.ndarray, what: str) -> None:
        self.model, self.values, self.what = model, values, what

    def __getitem__(self, j: int) -> np.ndarray:
        return self.model.row(self.values, j, self.what)


class GrowingKinematics:
    """FK and body Jacobians of ``frame`` for configurations added one at a time.

    A new configuration's factor is linearised alone (one single-configuration evaluation);
    when iSAM2 relinearises many kinematic factors at the same parameter values, the first few
    are computed singly and then every row at once, vectorised.
    """

    BATCH_AFTER = 4

    def __init__(self, robot: Robot, full_params: np.ndarray, released: list[str], frame: str) -> None:
        self.robot = robot
        self.base = np.array(full_params, dtype=float)
        self.released = list(released)
        self.index = np.array([robot.parameter_names.index(n) for n in released], dtype=int)
        self.frame = frame
        self.q: list[np.ndarray] = []
        self._key: bytes | None = None
        self._rows: dict[tuple[int, str], np.ndarray] = {}
        self._batched = False

    @property
    def n_released(self) -> int:
        return len(self.released)

    def add(self, q: np.ndarray) -> int:
        self.q.append(np.asarray(q, dtype=float))
        return len(self.q) - 1

    def full(self, released_values: np.ndarray) -> np.ndarray:
        params = self.base.copy()
        params[self.index] = released_values
        return params

    def poses(self, released_values: np.ndarray) -> _Row:
        return _Row(self, np.asarray(released_values, dtype=float), "pose")

    def jacobians(self, released_values: np.ndarray) -> _Row:
        return _Row(self, np.asarray(released_values, dtype=float), "jacobian")

    def row(self, values: np.ndarray, j: int, what: str) -> np.ndarray:
        key = values.tobytes()
        if key != self._key:
            self._key, self._rows, self._batched = key, {}, False
        if (j, what) not in self._rows:
            wanted = sorted({jj for jj, _ in self._rows} | {j})
            if len(wanted) > self.BATCH_AFTER and not self._batched:
                wanted, self._batched = list(range(len(self.q))), True
            self._evaluate(values, [jj for jj in wanted if (jj, what) not in self._rows] or [j])
        return self._rows[(j, what)]

    def _evaluate(self, values: np.ndarray, rows: list[int]) -> None:
        q = np.array([self.q[j] for j in rows])
        data = kinematics.forward(self.robot, self.full(values), q)
        poses = kinematics.frame_pose(self.robot, data, self.frame)
        jacobians = kinematics.jacobian(self.robot, data, self.released, frame=self.frame)
        for i, j in enumerate(rows):
            self._rows[(j, "pose")] = poses[i]
            self._rows[(j, "jacobian")] = jacobians[i]
