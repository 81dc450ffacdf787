"""The estimate of one calibration: parameters and auxiliary unknowns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class State:
    """Current estimate of everything: full parameter vector (SI) and auxiliary unknowns."""

    params: np.ndarray
    fixture_rotation: np.ndarray | None = None  # R_W_F, when estimated
    tracker_pose: np.ndarray | None = None  # T_T_W: the instrument (tracker, static camera) from W
    tool_points: np.ndarray | None = None  # (m, 3) in the flange frame: reflectors, a probe, a ball
    fixed_points: np.ndarray | None = None  # (k, 3) in W: the sockets a probe sits in, a ballbar's pivots
    tool_pose: np.ndarray | None = None  # T_n_E: a 6D probe's or a board's frame on the flange
    fixture_pose: np.ndarray | None = None  # T_W_F, when the projection formulation estimates it
    intrinsics: np.ndarray | None = None  # (fx, fy, cx, cy, k1, k2, p1, p2, k3), when estimated

    @property
    def n_auxiliary(self) -> int:
        """Number of auxiliary unknowns (tangent dimensions)."""
        count = 0
        if self.tracker_pose is not None:
            count += 6
        if self.tool_points is not None:
            count += 3 * len(self.tool_points)
        if self.fixed_points is not None:
            count += 3 * len(self.fixed_points)
        if self.tool_pose is not None:
            count += 6
        if self.fixture_rotation is not None:
            count += 3
        if self.fixture_pose is not None:
            count += 6
        if self.intrinsics is not None:
            count += 9
        return count
