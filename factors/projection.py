"""Camera projection factors with OpenCV's full pinhole model (SPEC section 4)."""

from __future__ import annotations

import numpy as np

from ..core.se3 import skew
from .base import Evaluation, MeasurementSet, OutsideModelError, RobustLoss, point_jacobian, row_starts
from .kinematics import Kinematics, params_variable


def project(intrinsics: np.ndarray, p_C: np.ndarray, jacobians: bool = False):
    """OpenCV projection of camera-frame points (..., 3) (m) to pixels (..., 2) (px).

    ``intrinsics`` = (fx, fy, cx, cy, k1, k2, p1, p2, k3). With ``jacobians``, also returns
    d pixel / d p_C (..., 2, 3) and d pixel / d intrinsics (..., 2, 9).
    """
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = np.asarray(intrinsics, dtype=float)
    p_C = np.asarray(p_C, dtype=float)
    x, y, z = p_C[..., 0], p_C[..., 1], p_C[..., 2]
    xn, yn = x / z, y / z
    r2 = xn * xn + yn * yn
    radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    # Filled in place: a projection set is a few dozen points, where np.stack's overhead is most
    # of the cost (the online update projects every image's set several times).
    pixel = np.empty((*z.shape, 2))
    pixel[..., 0], pixel[..., 1] = fx * xd + cx, fy * yd + cy
    if not jacobians:
        return pixel
    d_radial = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2  # d radial / d r2
    # d(xd, yd) / d(xn, yn)
    dxd_dxn = radial + 2.0 * xn * xn * d_radial + 2.0 * p1 * yn + 6.0 * p2 * xn
    dxd_dyn = 2.0 * xn * yn * d_radial + 2.0 * p1 * xn + 2.0 * p2 * yn
    dyd_dxn = dxd_dyn
    dyd_dyn = radial + 2.0 * yn * yn * d_radial + 6.0 * p1 * yn + 2.0 * p2 * xn
    inv_z = 1.0 / z
    # d pixel / d p_C = d pixel / d normalised  @  d normalised / d p_C
    a, b, c, d = fx * dxd_dxn, fx * dxd_dyn, fy * dyd_dxn, fy * dyd_dyn
    d_point = np.empty((*z.shape, 2, 3))
    d_point[..., 0, 0], d_point[..., 0, 1], d_point[..., 0, 2] = a * inv_z, b * inv_z, -(a * xn + b * yn) * inv_z
    d_point[..., 1, 0], d_point[..., 1, 1], d_point[..., 1, 2] = c * inv_z, d * inv_z, -(c * xn + d * yn) * inv_z
    r4 = r2 * r2
    d_intrinsics = np.zeros((*z.shape, 2, 9))  # columns fx fy cx cy k1 k2 p1 p2 k3
    row = d_intrinsics[..., 0, :]
    row[..., 0], row[..., 2] = xd, 1.0
    row[..., 4], row[..., 5], row[..., 8] = fx * xn * r2, fx * xn * r4, fx * xn * r4 * r2
    row[..., 6], row[..., 7] = fx * 2.0 * xn * yn, fx * (r2 + 2.0 * xn * xn)
    row = d_intrinsics[..., 1, :]
    row[..., 1], row[..., 3] = yd, 1.0
    row[..., 4], row[..., 5], row[..., 8] = fy * yn * r2, fy * yn * r4, fy * yn * r4 * r2
    row[..., 6], row[..., 7] = fy * (r2 + 2.0 * yn * yn), fy * 2.0 * xn * yn
    return pixel, d_point, d_intrinsics


def _pixel_set(
    owner: MeasurementSet,
    kinematics: Kinematics,
    params_key: int | None,
    pose_keys: list[int],
    configs: np.ndarray,
    points: np.ndarray,
    measured_px: np.ndarray,
    sigma_px: float,
    intrinsics: np.ndarray | None,
    intrinsics_key: int | None,
) -> None:
    """What every set of pixel observations holds: the points (their frame's coordinates), the
    pixels, the intrinsics as a constant or a variable after P and the Pose3 variables, and a
    pixel as the robust unit."""
    if (intrinsics is None) == (intrinsics_key is None):
        raise ValueError("give either constant intrinsics or an intrinsics variable key")
    owner.kinematics = kinematics
    owner.params_key = params_key
    owner.configs = np.asarray(configs, dtype=int)
    owner.points = np.asarray(points, dtype=float).reshape(-1, 3)
    owner.measured = np.asarray(measured_px, dtype=float).reshape(-1, 2)
    if not len(owner.configs) == len(owner.points) == len(owner.measured) or not len(owner.configs):
        raise ValueError("one configuration, point and pixel per observation, at least one")
    owner.intrinsics = None if intrinsics is None else np.asarray(intrinsics, dtype=float)
    owner.variables = [*params_variable(params_key, kinematics), *((key, "pose3", None) for key in pose_keys)]
    if intrinsics_key is not None:
        owner.variables.append((intrinsics_key, "vector", 9))
    owner.sigma = np.full(2 * len(owner.configs), float(sigma_px))
    owner.unit_starts = row_starts([2] * len(owner.configs))


class BehindCameraError(OutsideModelError):
    """A point projects from behind the camera: the estimate is far off."""


def _in_front(p_C: np.ndarray, configs: np.ndarray, what: str, estimate: str) -> None:
    """BehindCameraError unless every camera-frame point (O, 3) is in front of the camera."""
    if np.any(p_C[:, 2] <= 1e-6):
        worst = int(np.argmin(p_C[:, 2]))
        raise BehindCameraError(
            f"{what} behind the camera (depth {p_C[worst, 2]:.3g} m): {estimate} is far off",
            configuration=int(configs[worst]),
        )


class Projections(MeasurementSet):
    """``r_o = project(K, dist, X(P, q_j)^-1 O p_o) - z_o``  (px).

    A point ``p_o`` known in the object (fixture) frame O is seen at pixel ``z_o`` by the
    camera at configuration j, whose pose X (T_W_C) comes from the kinematics. ``O`` (T_W_O)
    is a Pose3 variable; the intrinsics (fx, fy, cx, cy, k1, k2, p1, p2, k3) a constant or,
    with ``intrinsics_key``, a 9-vector variable. Distortion follows OpenCV exactly, k3
    included (GTSAM's Cal3DS2 has no k3). The robust unit is one pixel observation.

    ``configs`` (O,): configuration index of each observation.
    """

    row_unit = "px"

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        object_key: int,
        configs: np.ndarray,
        points_O: np.ndarray,
        measured_px: np.ndarray,
        sigma_px: float,
        intrinsics: np.ndarray | None = None,
        intrinsics_key: int | None = None,
        robust: RobustLoss | None = None,
    ) -> None:
        _pixel_set(self, kinematics, params_key, [object_key], configs, points_O, measured_px, sigma_px,
                   intrinsics, intrinsics_key)  # fmt: skip
        super().__init__(robust)

    def camera_points(self, inputs: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Camera poses (O, 4, 4), the object pose, its points in W and in the camera (O, 3)."""
        params = inputs[0] if self.params_key is not None else None
        T_W_O = inputs[1 if self.params_key is not None else 0].matrix()
        T_W_C = self.kinematics.poses(params)[self.configs]
        p_W = self.points @ T_W_O[:3, :3].T + T_W_O[:3, 3]
        p_C = np.einsum("oji,oj->oi", T_W_C[:, :3, :3], p_W - T_W_C[:, :3, 3])
        return T_W_C, T_W_O, p_W, p_C

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        intrinsics = np.asarray(inputs[-1], dtype=float) if self.intrinsics is None else self.intrinsics
        T_W_C, T_W_O, _, p_C = self.camera_points(inputs)
        _in_front(p_C, self.configs, "point", "the pose estimate")
        if not jacobians:
            return Evaluation((project(intrinsics, p_C) - self.measured).reshape(-1), [])
        pixel, d_point, d_intrinsics = project(intrinsics, p_C, True)
        blocks = []
        R_C = T_W_C[:, :3, :3]
        if self.params_key is not None:
            # X Exp(xi): p_C -> p_C - omega x p_C - v, then xi = J_j dP.
            J = self.kinematics.jacobians(inputs[0])[self.configs]
            d_xi = np.concatenate([d_point @ skew(p_C), -d_point], axis=2)  # (O, 2, 6)
            blocks.append(np.matmul(d_xi, J).reshape(-1, J.shape[2]))
        # O Exp(eta): p_W -> p_W + R_O (omega x p_O + v)
        R_O = T_W_O[:3, :3]
        d_object = np.concatenate([-R_O @ skew(self.points), np.broadcast_to(R_O, (len(p_C), 3, 3))], axis=2)
        blocks.append(np.matmul(d_point @ np.swapaxes(R_C, 1, 2), d_object).reshape(-1, 6))
        if self.intrinsics is None:
            blocks.append(d_intrinsics.reshape(-1, 9))
        return Evaluation((pixel - self.measured).reshape(-1), blocks)


class StaticProjections(MeasurementSet):
    """``r_o = project(K, dist, L X(P, q_j) B p_o) - z_o``  (px).

    Eye-to-hand: a static camera sees a board carried by the robot. The board's point ``p_o``
    (board frame) is seen at pixel ``z_o`` at configuration j, whose flange pose X comes from
    the kinematics; ``L`` (T_C_W, the camera's pose) and ``B`` (T_n_B, the board's mounting on
    the flange) are Pose3 variables; the intrinsics as in :class:`Projections`. The robust unit
    is one pixel observation.
    """

    row_unit = "px"

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        camera_key: int,
        board_key: int,
        configs: np.ndarray,
        points_B: np.ndarray,
        measured_px: np.ndarray,
        sigma_px: float,
        intrinsics: np.ndarray | None = None,
        intrinsics_key: int | None = None,
        robust: RobustLoss | None = None,
    ) -> None:
        _pixel_set(self, kinematics, params_key, [camera_key, board_key], configs, points_B, measured_px, sigma_px,
                   intrinsics, intrinsics_key)  # fmt: skip
        super().__init__(robust)

    def camera_points(self, inputs: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Flange poses (O, 4, 4), the board's points on the flange (O, 3), in W and in the camera."""
        params = inputs[0] if self.params_key is not None else None
        first = 1 if self.params_key is not None else 0
        T_C_W, T_n_B = inputs[first].matrix(), inputs[first + 1].matrix()
        T_X = self.kinematics.poses(params)[self.configs]
        p_n = self.points @ T_n_B[:3, :3].T + T_n_B[:3, 3]
        p_W = np.einsum("oij,oj->oi", T_X[:, :3, :3], p_n) + T_X[:, :3, 3]
        p_C = p_W @ T_C_W[:3, :3].T + T_C_W[:3, 3]
        return T_X, p_n, p_W, p_C

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        intrinsics = np.asarray(inputs[-1], dtype=float) if self.intrinsics is None else self.intrinsics
        T_X, p_n, p_W, p_C = self.camera_points(inputs)
        _in_front(p_C, self.configs, "board point", "the camera pose estimate")
        if not jacobians:
            return Evaluation((project(intrinsics, p_C) - self.measured).reshape(-1), [])
        pixel, d_point, d_intrinsics = project(intrinsics, p_C, True)
        first = 1 if self.params_key is not None else 0
        R_L = inputs[first].matrix()[:3, :3]
        R_B = inputs[first + 1].matrix()[:3, :3]
        R_X = T_X[:, :3, :3]
        d_world = d_point @ R_L  # d pixel / d p_W
        blocks = []
        if self.params_key is not None:
            J = self.kinematics.jacobians(inputs[0])[self.configs]
            blocks.append(np.matmul(d_world @ point_jacobian(R_X, p_n), J).reshape(-1, J.shape[2]))
        blocks.append((d_point @ point_jacobian(R_L, p_W)).reshape(-1, 6))
        board = point_jacobian(np.broadcast_to(R_B, R_X.shape), self.points)  # d p_n / d B
        blocks.append((d_world @ R_X @ board).reshape(-1, 6))
        if self.intrinsics is None:
            blocks.append(d_intrinsics.reshape(-1, 9))
        return Evaluation((pixel - self.measured).reshape(-1), blocks)


class LinkProjections(MeasurementSet):
    """``r_o = project(K_c, (Y(P, q_j) M_c)^-1 X(P, q_j) B_k p_o) - z_o``  (px).

    Self-observation: camera c, mounted on a link of one chain (the link's pose Y in W from the
    kinematics, the camera on it ``M_c`` = T_link_C), sees point ``p_o`` of board k, carried by a
    tip of another chain (its pose X, the board on it ``B_k`` = T_tip_B), at pixel ``z_o``:
    projection through both chains. Every camera's mounting and every board's pose are Pose3
    variables (in that order, after P); the intrinsics of each camera are constants. The robust
    unit is one pixel observation.

    ``rows_camera``, ``rows_board`` (O,): the rows of the camera's link and of the board's tip
    among the kinematics' (frame-major) poses; ``cameras``, ``boards`` (O,): their indices.
    """

    row_unit = "px"

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        mounting_keys: list[int],
        board_keys: list[int],
        rows_camera: np.ndarray,
        rows_board: np.ndarray,
        cameras: np.ndarray,
        boards: np.ndarray,
        points_B: np.ndarray,
        measured_px: np.ndarray,
        sigma_px: float,
        intrinsics: np.ndarray,
        robust: RobustLoss | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.rows_camera, self.rows_board = np.asarray(rows_camera, dtype=int), np.asarray(rows_board, dtype=int)
        self.cameras, self.boards = np.asarray(cameras, dtype=int), np.asarray(boards, dtype=int)
        self.points = np.asarray(points_B, dtype=float).reshape(-1, 3)
        self.measured = np.asarray(measured_px, dtype=float).reshape(-1, 2)
        self.intrinsics = np.asarray(intrinsics, dtype=float).reshape(-1, 9)
        n = len(self.rows_camera)
        if not n or len({n, len(self.rows_board), len(self.cameras), len(self.boards), len(self.points),
                         len(self.measured)}) != 1:  # fmt: skip
            raise ValueError("a camera row, a board row, a camera, a board, a point and a pixel per observation")
        if len(self.intrinsics) != len(mounting_keys):
            raise ValueError("one set of intrinsics per camera")
        self.n_cameras, self.n_boards = len(mounting_keys), len(board_keys)
        self.variables = [
            *params_variable(params_key, kinematics),
            *((key, "pose3", None) for key in mounting_keys),
            *((key, "pose3", None) for key in board_keys),
        ]
        self.sigma = np.full(2 * n, float(sigma_px))
        self.unit_starts = row_starts([2] * n)
        self.configs = self.rows_camera % len(kinematics.q) if hasattr(kinematics, "q") else self.rows_camera
        super().__init__(robust)

    def camera_points(self, inputs: list) -> tuple[np.ndarray, ...]:
        """The link and tip poses (O, 4, 4), each observation's mounting and board (O, 4, 4), and
        its point on the tip, in W, on the link and in the camera (O, 3)."""
        params = inputs[0] if self.params_key is not None else None
        first = 1 if self.params_key is not None else 0
        mountings = np.array([m.matrix() for m in inputs[first : first + self.n_cameras]])
        boards = np.array([b.matrix() for b in inputs[first + self.n_cameras : first + self.n_cameras + self.n_boards]])
        poses = self.kinematics.poses(params)
        Y, X = poses[self.rows_camera], poses[self.rows_board]
        M, B = mountings[self.cameras], boards[self.boards]
        p_tip = np.einsum("oij,oj->oi", B[:, :3, :3], self.points) + B[:, :3, 3]
        p_W = np.einsum("oij,oj->oi", X[:, :3, :3], p_tip) + X[:, :3, 3]
        p_L = np.einsum("oji,oj->oi", Y[:, :3, :3], p_W - Y[:, :3, 3])
        p_C = np.einsum("oji,oj->oi", M[:, :3, :3], p_L - M[:, :3, 3])
        return Y, X, M, B, p_tip, p_W, p_L, p_C

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        Y, X, M, B, p_tip, _, p_L, p_C = self.camera_points(inputs)
        _in_front(p_C, self.configs, "board point", "the camera mounting or the board's pose")
        n = len(p_C)
        pixel = np.empty((n, 2))
        d_point = np.empty((n, 2, 3))
        for c in range(self.n_cameras):
            mine = self.cameras == c
            if jacobians:
                pixel[mine], d_point[mine], _ = project(self.intrinsics[c], p_C[mine], True)
            else:
                pixel[mine] = project(self.intrinsics[c], p_C[mine])
        residual = (pixel - self.measured).reshape(-1)
        if not jacobians:
            return Evaluation(residual, [])
        d_link = d_point @ np.swapaxes(M[:, :3, :3], 1, 2)  # d pixel / d p_L
        d_world = d_link @ np.swapaxes(Y[:, :3, :3], 1, 2)  # d pixel / d p_W
        blocks = []
        if self.params_key is not None:
            J = self.kinematics.jacobians(inputs[0])
            # Y Exp(xi): p_L -> p_L + p_L x omega - v; X Exp(xi): p_W -> p_W + R_X (omega x p_tip + v).
            through_link = np.concatenate([d_link @ skew(p_L), -d_link], axis=2) @ J[self.rows_camera]
            through_tip = d_world @ point_jacobian(X[:, :3, :3], p_tip) @ J[self.rows_board]
            blocks.append((through_link + through_tip).reshape(-1, J.shape[2]))
        # M Exp(eta): p_C -> p_C + p_C x omega - v.
        d_mounting = np.concatenate([d_point @ skew(p_C), -d_point], axis=2)
        for c in range(self.n_cameras):
            blocks.append((d_mounting * (self.cameras == c)[:, None, None]).reshape(-1, 6))
        d_board = d_world @ X[:, :3, :3] @ point_jacobian(B[:, :3, :3], self.points)
        for k in range(self.n_boards):
            blocks.append((d_board * (self.boards == k)[:, None, None]).reshape(-1, 6))
        return Evaluation(residual, blocks)
