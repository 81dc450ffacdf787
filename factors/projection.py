"""Camera projection factor with OpenCV's full pinhole model (SPEC section 4)."""

from __future__ import annotations

import gtsam
import numpy as np

from .base import CheckedFactor


def project(intrinsics: np.ndarray, p_C: np.ndarray, jacobians: bool = False):
    """OpenCV projection of a camera-frame point (m) to pixels (px).

    ``intrinsics`` = (fx, fy, cx, cy, k1, k2, p1, p2, k3). With ``jacobians``, also returns
    d pixel / d p_C (2x3) and d pixel / d intrinsics (2x9).
    """
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = intrinsics
    x, y, z = p_C
    xn, yn = x / z, y / z
    r2 = xn * xn + yn * yn
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    pixel = np.array([fx * xd + cx, fy * yd + cy])
    if not jacobians:
        return pixel
    d_radial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2  # d radial / d r2
    # d(xd, yd) / d(xn, yn)
    dxd_dxn = radial + 2.0 * xn * xn * d_radial + 2.0 * p1 * yn + 6.0 * p2 * xn
    dxd_dyn = 2.0 * xn * yn * d_radial + 2.0 * p1 * xn + 2.0 * p2 * yn
    dyd_dxn = 2.0 * xn * yn * d_radial + 2.0 * p1 * xn + 2.0 * p2 * yn
    dyd_dyn = radial + 2.0 * yn * yn * d_radial + 6.0 * p1 * yn + 2.0 * p2 * xn
    d_pixel_d_normalised = np.array([[fx * dxd_dxn, fx * dxd_dyn], [fy * dyd_dxn, fy * dyd_dyn]])
    d_normalised_d_point = np.array([[1.0 / z, 0.0, -x / (z * z)], [0.0, 1.0 / z, -y / (z * z)]])
    d_point = d_pixel_d_normalised @ d_normalised_d_point
    d_intrinsics = np.array(
        [
            [
                xd,
                0.0,
                1.0,
                0.0,
                fx * xn * r2,
                fx * xn * r2 * r2,
                fx * 2.0 * xn * yn,
                fx * (r2 + 2.0 * xn * xn),
                fx * xn * r2**3,
            ],
            [
                0.0,
                yd,
                0.0,
                1.0,
                fy * yn * r2,
                fy * yn * r2 * r2,
                fy * (r2 + 2.0 * yn * yn),
                fy * 2.0 * xn * yn,
                fy * yn * r2**3,
            ],
        ]
    )
    return pixel, d_point, d_intrinsics


class ProjectionFactor(CheckedFactor):
    """``r = project(K, dist, X_j^-1 O p_O) - z``  (px).

    A point ``p_O`` known in the object (or fixture) frame O, seen at pixel z by the camera
    at configuration j. ``X_j`` is the camera pose variable (T_W_C), ``O`` the object pose
    variable (T_W_O). The intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3) are a constant or,
    with ``intrinsics_key``, a 9-vector variable. Distortion follows OpenCV exactly,
    k3 included (GTSAM's Cal3DS2 has no k3).
    """

    def __init__(
        self,
        pose_key: int,
        object_key: int,
        point_O: np.ndarray,
        measured: np.ndarray,
        noise: gtsam.noiseModel.Base,
        sigmas: np.ndarray,
        intrinsics: np.ndarray | None = None,
        intrinsics_key: int | None = None,
    ) -> None:
        if (intrinsics is None) == (intrinsics_key is None):
            raise ValueError("give either constant intrinsics or an intrinsics variable key")
        self.point_O = np.asarray(point_O, dtype=float)
        self.measured = np.asarray(measured, dtype=float)
        self.intrinsics = None if intrinsics is None else np.asarray(intrinsics, dtype=float)
        variables = [(pose_key, "pose3", None), (object_key, "pose3", None)]
        if intrinsics_key is not None:
            variables.append((intrinsics_key, "vector", 9))
        super().__init__(variables, noise, sigmas)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        pose, obj = inputs[0].matrix(), inputs[1].matrix()
        intrinsics = np.asarray(inputs[2], dtype=float) if self.intrinsics is None else self.intrinsics
        R_X, R_O = pose[:3, :3], obj[:3, :3]
        p_W = R_O @ self.point_O + obj[:3, 3]
        p_C = R_X.T @ (p_W - pose[:3, 3])
        if p_C[2] <= 1e-6:
            raise ValueError(f"point behind the camera (depth {p_C[2]:.3g} m): the pose estimate is far off")
        if not jacobians:
            return project(intrinsics, p_C) - self.measured, []
        pixel, d_point, d_intrinsics = project(intrinsics, p_C, True)
        skew_c = np.array([[0.0, -p_C[2], p_C[1]], [p_C[2], 0.0, -p_C[0]], [-p_C[1], p_C[0], 0.0]])
        skew_o = np.array(
            [
                [0.0, -self.point_O[2], self.point_O[1]],
                [self.point_O[2], 0.0, -self.point_O[0]],
                [-self.point_O[1], self.point_O[0], 0.0],
            ]
        )
        # X Exp(xi): p_C -> p_C - omega x p_C - v;  O Exp(eta): p_W -> p_W + R_O (omega x p_O + v)
        d_pose = d_point @ np.hstack([skew_c, -np.eye(3)])
        d_object = d_point @ R_X.T @ np.hstack([-R_O @ skew_o, R_O])
        blocks = [d_pose, d_object]
        if self.intrinsics is None:
            blocks.append(d_intrinsics)
        return pixel - self.measured, blocks
