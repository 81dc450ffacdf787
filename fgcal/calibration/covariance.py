"""Marginal covariances of the estimated parameters and of predicted positions."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from .. import kinematics
from ..robot import Robot
from .graph import P_KEY, StageGraph, linearize


@dataclass
class JointCovariance:
    """Covariance of the released parameters and the auxiliary unknowns together (SI, tangent
    spaces for poses), scaled by the fit's variance factor where the caller says so."""

    offsets: dict[int, tuple[int, int]]  # key -> (first column, dimension)
    matrix: np.ndarray

    def block(self, keys: Sequence[int]) -> np.ndarray:
        index = np.concatenate([np.arange(a, a + d) for a, d in (self.offsets[k] for k in keys)])
        return self.matrix[np.ix_(index, index)]

    def scaled(self, factor: float) -> JointCovariance:
        return JointCovariance(self.offsets, self.matrix * factor)


def joint_covariance(stage: StageGraph, values: gtsam.Values) -> JointCovariance:
    """Covariance of (P, auxiliary unknowns) at ``values``: the inverse information of the
    stage's linearisation (measurement sets as one Jacobian each, priors), by QR of the
    column-scaled whitened Jacobian. QR rather than the normal equations (or gtsam.Marginals'
    Cholesky): the columns span lengths, angles and compliances (about 1e-7 rad/(N m)), whose
    spread the normal equations would square."""
    dims = {key: dim for key, (_, dim) in stage.aux.items()}
    if stage.released:
        dims = {P_KEY: stage.model.n_released, **dims}
    offsets, column = {}, 0
    for key, dim in dims.items():
        offsets[key] = (column, dim)
        column += dim
    linear = linearize(stage, values)
    rows = []
    for i in range(linear.size()):
        factor = linear.at(i)
        A, _ = factor.jacobian()
        dense, at = np.zeros((A.shape[0], column)), 0
        for key in factor.keys():  # noqa: SIM118 (a GaussianFactor, not a dict)
            start, dim = offsets[key]
            dense[:, start : start + dim] = A[:, at : at + dim]
            at += dim
        rows.append(dense)
    A = np.vstack(rows)
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    R = np.linalg.qr(A / scale, mode="r")
    R_inverse = np.linalg.pinv(R)  # the identifiability analysis keeps R well conditioned
    return JointCovariance(offsets, (R_inverse @ R_inverse.T) / np.outer(scale, scale))


def correlation(covariance: np.ndarray) -> np.ndarray:
    sigma = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    scale = np.where(sigma > 0, 1.0 / np.where(sigma > 0, sigma, 1.0), 0.0)
    return covariance * scale[:, None] * scale[None, :]


def position_covariance(
    robot: Robot,
    params: np.ndarray,
    released: Sequence[str],
    covariance: np.ndarray,
    q: np.ndarray,
    frame: str,
    point: np.ndarray,
    remove_common_offset: bool = False,
) -> np.ndarray:
    """Covariance (N, 3, 3) of the world position of ``point`` (fixed in ``frame``) at
    configurations q, carried from the parameter covariance through the FK Jacobian.

    With ``remove_common_offset``, of the positions minus their mean over the configurations
    (what scoring a relative calibration, whose translation is a gauge, measures).
    """
    if not released:
        return np.zeros((len(q), 3, 3))
    data = kinematics.forward(robot, params, np.atleast_2d(q))
    J = kinematics.jacobian(robot, data, list(released), frame=frame, point=point)
    if remove_common_offset:
        J = J - J.mean(axis=0, keepdims=True)
    return J @ covariance @ np.swapaxes(J, 1, 2)
