"""Gauges: what a score against the truth removes before measuring, because the data cannot fix
it (the translation of a relative calibration, the rigid motion where W is only where the
nominal base puts the robot)."""

from __future__ import annotations

import numpy as np

from ..core.se3 import kabsch, skew

GAUGES = ("none", "translation", "rigid")


def remove_gauge(predicted: np.ndarray, reference: np.ndarray, gauge: str) -> np.ndarray:
    """Residual positions (N, 3) after removing the gauge: 'none', 'translation' or 'rigid'."""
    if gauge == "none":
        return predicted - reference
    if gauge == "translation":
        difference = predicted - reference
        return difference - difference.mean(axis=0)
    R, t = kabsch(predicted, reference)
    return predicted @ R.T + t - reference


def without_gauge(J: np.ndarray, positions: np.ndarray, gauge: str) -> np.ndarray:
    """Rows (3N, m) of position Jacobians with the gauge's directions projected out: the
    common translation, or the infinitesimal rigid motions omega x (p - mean) + t."""
    if gauge == "none":
        return J
    n = len(positions)
    G = np.tile(np.eye(3), (n, 1))
    if gauge == "rigid":
        G = np.hstack([-skew(positions - positions.mean(axis=0)).reshape(-1, 3), G])
    Q, _ = np.linalg.qr(G)
    return J - Q @ (Q.T @ J)
