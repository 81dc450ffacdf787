"""Kinematics of a growing set of configurations, for the online measurement factors."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from ..model import kinematics
from ..model.robot import Robot


class _Row:
    """``model.poses(P)[j]`` / ``model.jacobians(P)[j]`` without computing every row."""

    def __init__(self, model: GrowingKinematics, values: np.ndarray, what: str) -> None:
        self.model, self.values, self.what = model, values, what

    def __getitem__(self, j: int) -> np.ndarray:
        return self.model.row(self.values, j, self.what)


class RowKinematics:
    """One configuration of a :class:`GrowingKinematics`, as the measurement factors ask for
    kinematics (fgcal.factors.Kinematics): index 0 is that row."""

    def __init__(self, model: GrowingKinematics, row: int) -> None:
        self.model, self.row = model, row
        self.n_released = model.n_released

    def poses(self, released_values: np.ndarray | None) -> np.ndarray:
        values = self.model.base[self.model.index] if released_values is None else released_values
        return self.model.row(np.asarray(values, dtype=float), self.row, "pose")[None]

    def jacobians(self, released_values: np.ndarray) -> np.ndarray:
        return self.model.row(np.asarray(released_values, dtype=float), self.row, "jacobian")[None]


class GrowingKinematics:
    """FK and body Jacobians of ``frame`` for configurations added one at a time.

    Each configuration belongs to a group (the parameter variable of its work cycle). The
    first request at new parameter values evaluates every live row of the group at once,
    vectorised: iSAM2 relinearises all the image factors of a parameter variable together.
    A configuration added later is evaluated alone. Rows whose factors have been marginalised
    are forgotten, so memory stays bounded.
    """

    CACHED_VALUES = 16

    def __init__(self, robot: Robot, full_params: np.ndarray, released: list[str], frame: str) -> None:
        self.robot = robot
        self.base = np.array(full_params, dtype=float)
        self.released = list(released)
        self.index = np.array([robot.parameter_names.index(n) for n in released], dtype=int)
        self.frame = frame
        self.q: dict[int, np.ndarray] = {}
        self.group: dict[int, int] = {}
        self._next = 0
        # values bytes -> {"rows": {(row, what): array}, "batched": groups evaluated whole}
        self._cache: OrderedDict[bytes, dict] = OrderedDict()

    @property
    def n_released(self) -> int:
        return len(self.released)

    def add(self, q: np.ndarray, group: int = 0) -> int:
        row = self._next
        self.q[row] = np.asarray(q, dtype=float)
        self.group[row] = group
        self._next += 1
        return row

    def forget_row(self, row: int) -> None:
        """Drop one configuration (an image that was not folded in)."""
        self.q.pop(row, None)
        self.group.pop(row, None)
        for entry in self._cache.values():
            for key in [k for k in entry["rows"] if k[0] == row]:
                del entry["rows"][key]

    def forget_before(self, row: int) -> None:
        """Drop the configurations before ``row`` (their factors are gone)."""
        for old in [r for r in self.q if r < row]:
            del self.q[old], self.group[old]
        for entry in self._cache.values():
            for key in [k for k in entry["rows"] if k[0] < row]:
                del entry["rows"][key]

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
        entry = self._cache.get(key)
        if entry is None:
            if len(self._cache) >= self.CACHED_VALUES:
                self._cache.popitem(last=False)
            entry = self._cache[key] = {"rows": {}, "batched": set()}
        rows = entry["rows"]
        if (j, what) not in rows:
            group = self.group[j]
            wanted = [j]
            if group not in entry["batched"]:
                entry["batched"].add(group)
                wanted = [r for r, g in self.group.items() if g == group and (r, what) not in rows]
            self._evaluate(values, wanted, rows)
        return rows[(j, what)]

    def _evaluate(self, values: np.ndarray, wanted: list[int], rows: dict) -> None:
        q = np.array([self.q[j] for j in wanted])
        data = kinematics.forward(self.robot, self.full(values), q)
        poses = kinematics.frame_pose(self.robot, data, self.frame)
        jacobians = kinematics.jacobian(self.robot, data, self.released, frame=self.frame)
        for i, j in enumerate(wanted):
            # Copies: a view would keep the whole evaluation (every frame of the chain) alive.
            rows[(j, "pose")] = poses[i].copy()
            rows[(j, "jacobian")] = jacobians[i].copy()
