"""ChArUco boards on the calibration objects' sides: geometry, rendering, detection.

Each grid-carrying side carries one ChArUco board whose squares are the grid pitch, so its
inner chessboard corners are exactly the side's grid points. The board's x axis runs along the
grid columns or rows, chosen so that it reads correctly from outside the object (x × y
points into the object, as OpenCV's board frame does). Marker ids are consecutive per side,
so that every board in the cell has its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .boards import DICTIONARY, SideBoard
from .camera import Camera
from .dataset import Table
from .errors import InputError
from .se3 import inverse, pose
from .simulation.cell import Side


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


@dataclass
class Detection:
    """Detected grid points of one image: names, pixels (N, 2), and what was rejected."""

    names: list[str]
    pixels: np.ndarray
    rejected: int = 0
    message: str = ""


class Detector:
    """ArUco markers once per image, then each board's ChArUco corners (sub-pixel), then a
    PnP-RANSAC gate per board that rejects corners more than ``gate_px`` from the fit."""

    def __init__(self, boards: list[SideBoard], camera: Camera, gate_px: float = 2.0) -> None:
        self.boards = boards
        self.camera = camera
        self.gate_px = gate_px
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
        parameters = cv2.aruco.DetectorParameters()
        parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self.marker_detector = cv2.aruco.ArucoDetector(dictionary, parameters)
        charuco = cv2.aruco.CharucoParameters()
        charuco.cameraMatrix = camera.K
        charuco.distCoeffs = camera.distortion
        # One adjacent marker suffices for a corner (OpenCV's default of two loses corners at
        # the edge of what a marker pair covers); every corner is still checked by the gate.
        charuco.minMarkers = 1
        self.charuco = [cv2.aruco.CharucoDetector(b.opencv(), charuco) for b in boards]

    def detect(self, image: np.ndarray) -> Detection:
        corners, ids, _ = self.marker_detector.detectMarkers(image)
        if ids is None or len(ids) == 0:
            return Detection([], np.zeros((0, 2)), message="no markers found")
        ids = ids.ravel()
        names, pixels, rejected = [], [], 0
        for board, detector in zip(self.boards, self.charuco, strict=True):
            mine = (ids >= board.first_id) & (ids < board.first_id + board.n_markers)
            if mine.sum() < 2:
                continue
            board_corners, board_ids, _, _ = detector.detectBoard(
                image, markerCorners=[corners[i] for i in np.flatnonzero(mine)], markerIds=ids[mine].reshape(-1, 1)
            )
            if board_ids is None or len(board_ids) < 4:
                continue
            found = [board.corner_names[int(k)] for k in board_ids.ravel()]
            uv = board_corners.reshape(-1, 2).astype(np.float64)
            keep = self._gate(detector.getBoard().getChessboardCorners()[board_ids.ravel()], uv)
            rejected += int((~keep).sum())
            names += [n for n, k in zip(found, keep, strict=True) if k]
            pixels.append(uv[keep])
        if not names:
            return Detection([], np.zeros((0, 2)), rejected, "no ChArUco corners found")
        return Detection(names, np.vstack(pixels), rejected)

    def _gate(self, board_points: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Inliers of a PnP-RANSAC fit in the board's own (planar, z = 0) coordinates."""
        ok, _, _, inliers = cv2.solvePnPRansac(
            board_points.astype(np.float64),
            uv,
            self.camera.K,
            self.camera.distortion,
            reprojectionError=self.gate_px,
            iterationsCount=200,
            flags=cv2.SOLVEPNP_IPPE,
        )
        keep = np.zeros(len(uv), dtype=bool)
        if ok and inliers is not None:
            keep[inliers.ravel()] = True
        return keep


@dataclass
class ImageDetections:
    """Detections over a dataset's images: a pixels table, and what was skipped and why."""

    pixels: object  # fgcal.dataset.Table
    skipped: list[tuple[str, str]]
    corners: int
    rejected: int


def detect_images(dataset, gate_px: float = 2.0, progress=None) -> ImageDetections:
    """Detect every configuration's image ``<config>.png``. An unreadable image or one without
    markers is skipped and reported; nothing else is lost."""
    if dataset.images_dir is None or not dataset.boards or dataset.camera is None:
        raise InputError(
            dataset.path / "dataset.yaml",
            "images",
            "detection needs images, markers (the boards) and the camera intrinsics",
        )
    detector = Detector(dataset.boards, dataset.camera, gate_px)
    configs, names, pixels, skipped, rejected = [], [], [], [], 0
    for i, cid in enumerate(dataset.configs):
        path = dataset.images_dir / f"{cid}.png"
        if not path.exists():
            skipped.append((str(cid), f"missing {path.name}"))
            continue
        try:
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        except cv2.error as error:  # e.g. a header claiming more pixels than OpenCV decodes
            image, reason = None, f"cannot read {path.name}: {str(error).strip().splitlines()[-1]}"
        else:
            reason = f"cannot read {path.name} (empty, truncated or not an image)"
        if image is None:
            skipped.append((str(cid), reason))
            continue
        detection = detector.detect(image)
        rejected += detection.rejected
        if not detection.names:
            skipped.append((str(cid), detection.message))
            continue
        configs += [cid] * len(detection.names)
        names += detection.names
        pixels.append(detection.pixels)
        if progress and (i + 1) % 50 == 0:
            progress(f"  detected {i + 1}/{len(dataset.configs)} images")
    table = Table(
        {"config": np.array(configs, dtype=object), "point": np.array(names, dtype=object)},
        np.vstack(pixels) if pixels else np.zeros((0, 2)),
    )
    return ImageDetections(table, skipped, len(names), rejected)
