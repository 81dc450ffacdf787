"""Which parameters an online calibration can release, before any image has arrived.

The online graph holds one parameter vector for the whole run, so its released set is
chosen up front: the parameters that camera poses seen relative to an unknown fixture
determine in general position. Each configuration contributes the camera's body twist
Jacobian ``J_j`` (6 x m, whitened by a pose sigma typical of one image); the fixture pose
is an auxiliary unknown with columns ``Ad(T_W_C,j)^-1``. The selection is the batch
calibration's (:func:`fgcal.calibration.identifiability.select`): parameters that are
combinations of others or have no effect stay at their starting values.
"""

from __future__ import annotations

import numpy as np

from ..calibration.identifiability import Identifiability, select
from ..core.se3 import inverse, skew
from ..model import kinematics
from ..model.parameters import MASS_KIND, MOTION_KINDS, split_name
from ..model.robot import Robot

# Pose sigma of one image of a few points at working distance (rad, m): the scale at which
# min_information is judged, as the batch calibration judges it at its measurement sigmas.
IMAGE_POSE_SIGMA = (1e-4, 3e-5)


def candidates(robot: Robot, compliant_joints: tuple[int, ...]) -> list[str]:
    """Every parameter except the base (which defines W), the motion history's terms (an
    inbox's images carry no history) and mass scales (which need many configurations' gravity
    moments), with compliances only for ``compliant_joints``."""

    def wanted(name: str) -> bool:
        kind, owner = split_name(name)
        if owner == "base" or kind in (*MOTION_KINDS, MASS_KIND):
            return False
        return owner in compliant_joints if kind in ("kx", "ky", "kz", "kc") else True

    return [n for n in robot.parameter_names if wanted(n)]


def structural_identifiability(
    robot: Robot,
    params: np.ndarray,
    names: list[str],
    n_configurations: int = 300,
    seed: int = 0,
    min_information: float = 3.0,
) -> Identifiability:
    """Identifiability of ``names`` from camera poses at configurations drawn uniformly
    within the joint limits (seeded), the fixture pose unknown."""
    rng = np.random.default_rng(seed)
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q = rng.uniform(low, high, (n_configurations, robot.n_joints))
    data = kinematics.forward(robot, params, q)
    J_body = kinematics.jacobian(robot, data, names, frame="tool")  # (N, 6, m)
    T_W_C = kinematics.frame_pose(robot, data, "tool")
    T_C_W = inverse(T_W_C)
    rotation, translation = T_C_W[:, :3, :3], T_C_W[:, :3, 3]
    # Adjoint of T_C_W maps the fixture's world twist into the camera's body frame.
    adjoint = np.zeros((n_configurations, 6, 6))
    adjoint[:, :3, :3] = rotation
    adjoint[:, 3:, 3:] = rotation
    adjoint[:, 3:, :3] = skew(translation) @ rotation
    whiten = 1.0 / np.repeat(IMAGE_POSE_SIGMA, 3)[None, :, None]
    J_p = (whiten * J_body).reshape(-1, len(names))
    J_aux = (whiten * adjoint).reshape(-1, 6)
    return select(J_p, J_aux, names, data.moments, min_information)
