"""Kinematics of every configuration at once, shared by the measurement factors of one graph."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..model import kinematics
from ..model.robot import Robot

# Evaluations kept. Each holds every frame of the chain at every configuration (tens of MB at
# thousands), and GTSAM's Levenberg-Marquardt never returns to a point it left: its measurement
# sets ask one after the other at the same values. One, two or four kept evaluate the kinematics
# as often (forward / Jacobian: 48/68 on the dual-arm cell, 24/18 on the seed cell at 3000
# configurations, 81/59 on the FARO set).
CACHED_POINTS = 1


class BatchKinematics:
    """FK (N, 4, 4) and body Jacobians (N, 6, m) of ``frame`` at all configurations ``q``,
    reached as their motion-history features ``motion`` (N, 2n) say (None: no history), as
    functions of the m released parameters; the others stay at ``full_params``. ``frame`` may
    name several frames (the tips of a tree): the poses are then (F N, 4, 4), frame-major (row
    ``f N + j`` is frame f at configuration j), and so are the Jacobians.

    Results are cached on the released values: when GTSAM evaluates or linearises the
    graph, the first measurement set to ask triggers one vectorised evaluation and the
    others reuse it (fgcal.factors.Kinematics).
    """

    def __init__(
        self,
        robot: Robot,
        full_params: np.ndarray,
        released: Sequence[str],
        q: np.ndarray,
        frame: str | Sequence[str],
        motion: np.ndarray | None,
    ) -> None:
        self.robot = robot
        self.base = np.array(full_params, dtype=float)
        self.released = list(released)
        self.index = np.array([robot.parameter_names.index(name) for name in self.released], dtype=int)
        self.q = np.asarray(q, dtype=float)
        self.frame = frame
        self.frames = (frame,) if isinstance(frame, str) else tuple(frame)
        self.motion = motion
        self._cache: dict[bytes, dict] = {}

    @property
    def n_released(self) -> int:
        return len(self.released)

    def full(self, released_values: np.ndarray) -> np.ndarray:
        params = self.base.copy()
        params[self.index] = released_values
        return params

    def _entry(self, released_values: np.ndarray | None) -> dict:
        values = self.base[self.index] if released_values is None else np.asarray(released_values, dtype=float)
        key = values.tobytes()
        entry = self._cache.get(key)
        if entry is None:
            if len(self._cache) >= CACHED_POINTS:
                self._cache.pop(next(iter(self._cache)))
            data = kinematics.forward(self.robot, self.full(values), self.q, self.motion)
            poses = [kinematics.frame_pose(self.robot, data, frame) for frame in self.frames]
            entry = {"data": data, "poses": poses[0] if len(poses) == 1 else np.concatenate(poses)}
            self._cache[key] = entry
        return entry

    def keep_only(self, released_values: np.ndarray | None) -> None:
        """Forget every evaluation but the one at these values (if there is one)."""
        values = self.base[self.index] if released_values is None else np.asarray(released_values, dtype=float)
        kept = self._cache.get(values.tobytes())
        self._cache = {} if kept is None else {values.tobytes(): kept}

    def forget(self) -> None:
        """Forget every evaluation (a graph not in use: its next use evaluates again)."""
        self._cache = {}

    def data(self, released_values: np.ndarray | None) -> kinematics.KinematicsData:
        """The full kinematics evaluation (frames, gravity moments) at these values."""
        return self._entry(released_values)["data"]

    def poses(self, released_values: np.ndarray | None) -> np.ndarray:
        return self._entry(released_values)["poses"]

    def jacobians(self, released_values: np.ndarray) -> np.ndarray:
        entry = self._entry(released_values)
        if "jacobians" not in entry:
            jacobians = [
                kinematics.jacobian(self.robot, entry["data"], self.released, frame=frame) for frame in self.frames
            ]
            entry["jacobians"] = jacobians[0] if len(jacobians) == 1 else np.concatenate(jacobians)
        return entry["jacobians"]
