"""Point-pair factor of the seed's relative formulation (SPEC section 4, eq. 3)."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import CheckedFactor, point_jacobian


class PointPairFactor(CheckedFactor):
    """``r_h = X_j c_u - X_k c_v + R_W_F uv_F`` for every pair h of the factor  (m).

    ``c_u`` (M, 3): points U measured in the camera frame at configuration j; ``c_v`` (M, 3):
    points V measured at configuration k; ``uv_F`` (M, 3) = V - U from the object drawings, in
    the fixture frame F. The fixture orientation ``R_W_F`` is a constant (``fixture_rotation``)
    or, with ``fixture_key``, a Rot3 variable. With j == k (pairs within one image) the
    factor has one pose variable.
    """

    def __init__(
        self,
        pose_j: int,
        pose_k: int,
        c_u: np.ndarray,
        c_v: np.ndarray,
        uv_F: np.ndarray,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
        fixture_key: int | None = None,
        fixture_rotation: np.ndarray | None = None,
    ) -> None:
        self.c_u, self.c_v, self.uv_F = (np.asarray(a, dtype=float).reshape(-1, 3) for a in (c_u, c_v, uv_F))
        self.same_pose = pose_j == pose_k
        self.fixture_rotation = np.eye(3) if fixture_rotation is None else np.asarray(fixture_rotation, float)
        variables = [(pose_j, "pose3", None)] + ([] if self.same_pose else [(pose_k, "pose3", None)])
        if fixture_key is not None:
            variables.append((fixture_key, "rot3", None))
        self.estimate_fixture = fixture_key is not None
        super().__init__(variables, noise, sigmas)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        pose_j = inputs[0]
        pose_k = pose_j if self.same_pose else inputs[1]
        R_W_F = inputs[-1].matrix() if self.estimate_fixture else self.fixture_rotation
        T_j, T_k = pose_j.matrix(), pose_k.matrix()
        x_u = self.c_u @ T_j[:3, :3].T + T_j[:3, 3]
        x_v = self.c_v @ T_k[:3, :3].T + T_k[:3, 3]
        uv_W = self.uv_F @ R_W_F.T
        residual = (x_u - x_v + uv_W).reshape(-1)
        if not jacobians:
            return residual, []
        d_j = np.vstack([point_jacobian(T_j[:3, :3], c) for c in self.c_u])
        d_k = -np.vstack([point_jacobian(T_k[:3, :3], c) for c in self.c_v])
        blocks = [d_j + d_k] if self.same_pose else [d_j, d_k]
        if self.estimate_fixture:
            # R Exp(w) uv = R uv + R (w x uv) = R uv - R [uv]x w
            blocks.append(np.vstack([point_jacobian(R_W_F, uv)[:, :3] for uv in self.uv_F]))
        return residual, blocks
