"""Detection of the ChArUco boards on the calibration objects in real (or rendered) images:
ArUco markers, each board's corners, a PnP gate per board; a dataset's images into a pixel table.

The boards themselves are declared by the dataset (fgcal.model.boards);
fgcal.simulation.markers renders them."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..core.errors import InputError
from ..model.boards import DICTIONARY, SideBoard
from ..model.camera import Camera
from .dataset import Table


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

    pixels: object  # fgcal.data.dataset.Table
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
