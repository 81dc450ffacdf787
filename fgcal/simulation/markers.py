"""ChArUco boards on the calibration objects' sides: their geometry and rendering (detection: fgcal.data.images).

Each grid-carrying side carries one ChArUco board whose squares are the grid pitch, so its
inner chessboard corners are exactly the side's grid points. The board's x axis runs along the
grid columns or rows, chosen so that it reads correctly from outside the object (x × y
points into the object, as OpenCV's board frame does). Marker ids are consecutive per side,
so that every board in the cell has its own.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..core.se3 import inverse, pose
from ..model.boards import SideBoard
from ..model.camera import Camera
from .cell import Side


def side_boards(sides: list[Side], fixture_pose: np.ndarray | None = None) -> list[SideBoard]:
    """One board per side, its corners on the side's grid."""
    boards, first_id = [], 0
    for side in sides:
        grid = np.array([[p.position_F for p in row] for row in side.points])  # (rows, cols, 3)
        names = [[p.name for p in row] for row in side.points]
        along_cols = grid[0, 1] - grid[0, 0]
        along_rows = grid[1, 0] - grid[0, 0]
        pitch = float(np.linalg.norm(along_cols))
        e1, e2 = along_cols / pitch, along_rows / np.linalg.norm(along_rows)
        if np.dot(np.cross(e1, e2), side.normal_F) > 0:
            # Seen from outside this board would be mirrored: run its x along the rows instead.
            grid, names = np.swapaxes(grid, 0, 1), [list(col) for col in zip(*names, strict=True)]
            e1, e2 = e2, e1
        n_y, n_x = grid.shape[:2]
        origin = grid[0, 0] - pitch * e1 - pitch * e2
        T_F_B = pose(np.stack([e1, e2, np.cross(e1, e2)], axis=1), origin)
        corner_names = tuple(names[k // n_x][k % n_x] for k in range(n_x * n_y))
        board = SideBoard(f"{side.obj}{side.side}", (n_x + 1, n_y + 1), pitch, first_id, T_F_B, corner_names)
        boards.append(board)
        first_id += board.n_markers
    return boards


class Renderer:
    """Synthetic images of one board seen by a camera: exact pinhole projection with OpenCV's
    distortion (per-pixel rays), bilinear texture lookup, Gaussian blur and pixel noise."""

    def __init__(self, camera: Camera, texture_px_per_m: float = 6000.0) -> None:
        self.camera = camera
        self.scale = texture_px_per_m
        u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
        pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        normalised = cv2.undistortPointsIter(
            pixels,
            camera.K,
            camera.distortion,
            None,
            None,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12),
        )
        self.rays = np.concatenate([normalised.reshape(-1, 2), np.ones((pixels.shape[0], 1))], axis=1)
        self._textures: dict[str, np.ndarray] = {}

    def texture(self, board: SideBoard) -> np.ndarray:
        if board.name not in self._textures:
            size = (
                round(board.squares[0] * board.square_m * self.scale),
                round(board.squares[1] * board.square_m * self.scale),
            )
            self._textures[board.name] = board.opencv().generateImage(size, marginSize=0, borderBits=1)
        return self._textures[board.name]

    def render(
        self,
        board: SideBoard,
        T_C_B: np.ndarray,
        rng: np.random.Generator,
        blur_px: float = 0.7,
        noise_grey: float = 2.0,
        background: int = 90,
    ) -> np.ndarray:
        """8-bit grey image of ``board`` at pose ``T_C_B`` (board in the camera frame)."""
        R, t = T_C_B[:3, :3], T_C_B[:3, 3]
        normal = R[:, 2]
        denominator = self.rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (normal @ t) / denominator
        hit = (depth > 0) & np.isfinite(depth)
        points = self.rays * np.where(hit, depth, 0.0)[:, None] - t
        board_xy = points @ R[:, :2]
        texture = self.texture(board)
        # Texel i covers [i, i+1) with its centre at i + 0.5 (OpenCV samples at centres).
        map_x = (board_xy[:, 0] * self.scale - 0.5).astype(np.float32)
        map_y = (board_xy[:, 1] * self.scale - 0.5).astype(np.float32)
        map_x[~hit] = -1.0
        shape = (self.camera.height, self.camera.width)
        image = cv2.remap(
            texture,
            map_x.reshape(shape),
            map_y.reshape(shape),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=background,
        ).astype(np.float64)
        if blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        image += rng.normal(0.0, noise_grey, image.shape)
        return np.clip(np.round(image), 0, 255).astype(np.uint8)


def board_pose_in_camera(T_W_C: np.ndarray, T_W_F: np.ndarray, board: SideBoard) -> np.ndarray:
    return inverse(T_W_C) @ T_W_F @ board.T_F_B
