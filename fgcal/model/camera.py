"""Pinhole camera with OpenCV's distortion model (k1, k2, p1, p2, k3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.fields import Fields


@dataclass(frozen=True)
class Camera:
    """Intrinsics in px, image size (width, height) in px."""

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: np.ndarray  # (5,) k1 k2 p1 p2 k3
    width: int
    height: int

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_C: np.ndarray) -> np.ndarray:
        """Pixels (M, 2) of points (M, 3) given in the camera frame (m)."""
        import cv2  # loaded when used: commands without images or cameras skip it

        pts = np.ascontiguousarray(points_C, dtype=np.float64).reshape(-1, 1, 3)
        pixels, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.distortion)
        return pixels.reshape(-1, 2)

    def sees(self, points_C: np.ndarray, margin_px: float = 10.0, min_depth_m: float = 0.05) -> bool:
        """Every point in front of the camera and inside the image with a margin."""
        if np.any(points_C[:, 2] < min_depth_m):
            return False
        # Far off-axis points can fold back into the image under strong distortion; the
        # undistorted normalised coordinates must stay inside a sane field of view too.
        normalised = points_C[:, :2] / points_C[:, 2:3]
        if np.any(np.abs(normalised) > 1.5):
            return False
        px = self.project(points_C)
        return bool(
            np.all(
                (px[:, 0] >= margin_px)
                & (px[:, 0] <= self.width - margin_px)
                & (px[:, 1] >= margin_px)
                & (px[:, 1] <= self.height - margin_px)
            )
        )

    def to_document(self) -> dict:
        return {
            "image_size": [self.width, self.height],
            "intrinsics": {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy},
            "distortion": [float(v) for v in self.distortion],
        }


def parse_camera(fields: Fields) -> Camera:
    """Read ``image_size``, ``intrinsics`` {fx, fy, cx, cy} (px) and ``distortion`` (5)."""
    size = fields.vector("image_size", 2)
    if np.any(size < 1) or np.any(size != np.round(size)):
        raise fields.error("image_size", f"expected two positive integers (width, height) in px, got {size.tolist()}")
    intr = fields.sub("intrinsics")
    return Camera(
        fx=intr.number("fx", positive=True),
        fy=intr.number("fy", positive=True),
        cx=intr.number("cx"),
        cy=intr.number("cy"),
        distortion=fields.vector("distortion", 5, [0, 0, 0, 0, 0]),
        width=int(size[0]),
        height=int(size[1]),
    )


def solve_pnp(object_points: np.ndarray, image_points: np.ndarray, camera: Camera) -> np.ndarray | None:
    """T_C_O of points known in a frame O, from their pixels; None when OpenCV fails.

    The points are centred on their centroid first: IPPE (the planar solver, for points on
    one board or side) is numerically poor for points far from the origin of their frame,
    which calibration objects placed in a cell are.
    """
    import cv2  # loaded when used: commands without images or cameras skip it

    object_points = np.asarray(object_points, dtype=np.float64)
    centroid = object_points.mean(axis=0)
    centred = object_points - centroid
    planar = np.linalg.svd(centred, compute_uv=False)[-1] < 1e-6 * max(1.0, np.abs(centred).max())
    flags = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
    ok, rvec, tvec = cv2.solvePnP(
        centred, np.asarray(image_points, dtype=np.float64), camera.K, camera.distortion, flags=flags
    )
    if not ok:
        return None
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel() - T[:3, :3] @ centroid
    return T
