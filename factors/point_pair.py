"""Point-pair factor of the seed's relative formulation (SPEC section 4, eq. 3)."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import CheckedFactor


def helmert(count: int) -> np.ndarray:
    """(count-1, count) orthonormal contrasts: rows sum to zero and are orthonormal.

    Row 0 is (e_1 - e_2)/sqrt(2); row r contrasts observation r+2 with the mean of the
    first r+1 ones.
    """
    rows = np.zeros((count - 1, count))
    for r in range(count - 1):
        k = r + 1
        rows[r, :k] = 1.0
        rows[r, k] = -k
        rows[r] /= np.sqrt(k * (k + 1))
    return rows


class PointPairFactor(CheckedFactor):
    """``r = H (X_j(o) c_o - R_W_F p_o)`` over the observations o of a group  (m).

    Observation o: point with drawing coordinates ``p_o`` (fixture frame F) measured at
    ``c_o`` in the camera frame of configuration j(o). H holds the orthonormal contrasts
    (:func:`helmert`): each row is a combination of the seed's point-pair residuals
    ``X_j c_u - X_k c_v + R_W_F (p_V - p_U)`` (eq. 3; row 0 is the pair of the first two
    observations over sqrt 2), and together they carry every point pair of the group. With
    independent measurement noise sigma per coordinate the rows have covariance sigma^2 I
    exactly, however many pairs share an observation. The unknown common position of the
    points (the base) cancels. ``R_W_F`` is a constant or, with ``fixture_key``, a Rot3
    variable.
    """

    def __init__(
        self,
        pose_keys: list[int],
        owner: np.ndarray,
        c: np.ndarray,
        p_F: np.ndarray,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
        fixture_key: int | None = None,
        fixture_rotation: np.ndarray | None = None,
    ) -> None:
        self.owner = np.asarray(owner, dtype=int)  # observation -> index into pose_keys
        self.c = np.asarray(c, dtype=float).reshape(-1, 3)
        self.p_F = np.asarray(p_F, dtype=float).reshape(-1, 3)
        if len(self.c) < 2 or not len(self.c) == len(self.p_F) == len(self.owner):
            raise ValueError("a point-pair factor needs at least two observations, each with a drawing point")
        self.contrasts = helmert(len(self.c))
        self.fixture_rotation = np.eye(3) if fixture_rotation is None else np.asarray(fixture_rotation, float)
        self.estimate_fixture = fixture_key is not None
        variables = [(key, "pose3", None) for key in pose_keys]
        if fixture_key is not None:
            variables.append((fixture_key, "rot3", None))
        super().__init__(variables, noise, sigmas)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        n_poses = len(inputs) - (1 if self.estimate_fixture else 0)
        poses = [inputs[i].matrix() for i in range(n_poses)]
        R_W_F = inputs[-1].matrix() if self.estimate_fixture else self.fixture_rotation
        rotations = np.array([T[:3, :3] for T in poses])[self.owner]
        translations = np.array([T[:3, 3] for T in poses])[self.owner]
        world = np.einsum("oij,oj->oi", rotations, self.c) + translations - self.p_F @ R_W_F.T
        residual = (self.contrasts @ world).reshape(-1)
        if not jacobians:
            return residual, []
        # d world_o / d xi of its pose = [-R [c_o]x, R]; a pose's block sums its observations
        # through the contrasts.
        skew = np.zeros((len(self.c), 3, 3))
        skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -self.c[:, 2], self.c[:, 1], -self.c[:, 0]
        skew -= np.swapaxes(skew, 1, 2)
        per_obs = np.concatenate([-rotations @ skew, rotations], axis=2)  # (O, 3, 6)
        rows = self.contrasts.shape[0]
        blocks = []
        for i in range(n_poses):
            mine = self.owner == i
            blocks.append(np.einsum("ro,oab->rab", self.contrasts[:, mine], per_obs[mine]).reshape(3 * rows, 6))
        if self.estimate_fixture:
            # d(-R Exp(w) p)/dw = R [p]x
            skew_p = np.zeros((len(self.p_F), 3, 3))
            skew_p[:, 0, 1], skew_p[:, 0, 2], skew_p[:, 1, 2] = -self.p_F[:, 2], self.p_F[:, 1], -self.p_F[:, 0]
            skew_p -= np.swapaxes(skew_p, 1, 2)
            blocks.append(np.einsum("ro,oab->rab", self.contrasts, R_W_F @ skew_p).reshape(3 * rows, 3))
        return residual, blocks
