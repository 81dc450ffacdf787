"""Marginal covariances of the estimated parameters and of predicted positions."""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from .. import kinematics
from ..robot import Robot
from .graph import P_KEY, StageGraph, linearize


def parameter_covariance(stage: StageGraph, values: gtsam.Values) -> np.ndarray:
    """Marginal covariance (m x m) of the released parameters, SI units squared.

    The linearised graph is eliminated with QR in the order auxiliary unknowns, P, so that P
    ends in the root clique, from which the Bayes tree gives its marginal. QR rather than
    gtsam.Marginals' Cholesky: the columns span lengths, angles and compliances (about 1e-7
    rad/(N m)), whose spread the normal equations would square.
    """
    if not stage.released:
        return np.zeros((0, 0))
    ordering = gtsam.Ordering()
    for key in [*stage.aux, P_KEY]:
        ordering.push_back(key)
    bayes_tree = linearize(stage, values).eliminateMultifrontal(ordering, gtsam.EliminateQR)
    return bayes_tree.marginalCovariance(P_KEY)


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
