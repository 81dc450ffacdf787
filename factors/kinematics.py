"""What the measurement factors need of the robot's kinematics."""

from __future__ import annotations

from typing import Protocol

import numpy as np


class Kinematics(Protocol):
    """Poses and body Jacobians of the measured frame (camera, flange) at a set of
    configurations, as functions of the m released parameters P; implementations cache them
    on P, so that every factor of a graph shares one vectorised evaluation.

    ``poses(P)`` is (N, 4, 4), T_W_frame; ``poses(None)`` the poses at the fixed parameters
    (nothing released). ``jacobians(P)`` is (N, 6, m): body twists [omega, v] per parameter.
    """

    n_released: int

    def poses(self, released_values: np.ndarray | None) -> np.ndarray: ...

    def jacobians(self, released_values: np.ndarray) -> np.ndarray: ...


def params_variable(params_key: int | None, kinematics: Kinematics) -> list[tuple[int, str, int | None]]:
    """The parameter vector P as a factor variable, or none when nothing is released."""
    return [] if params_key is None else [(params_key, "vector", kinematics.n_released)]
