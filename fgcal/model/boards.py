"""The ChArUco board on a calibration object's side: its description, as a dataset declares
it (markers: in dataset.yaml) as fgcal.simulation.markers renders it and fgcal.data.images detects it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core.se3 import rpy_from_rotation

if TYPE_CHECKING:
    import cv2

DICTIONARY = "DICT_5X5_1000"
MARKER_RATIO = 0.75  # marker side / square side


@dataclass(frozen=True)
class SideBoard:
    """A side's ChArUco board: T_F_B (board frame in the fixture frame, m), squares (x, y),
    first marker id, and the grid point name of each ChArUco corner id."""

    name: str
    squares: tuple[int, int]
    square_m: float
    first_id: int
    T_F_B: np.ndarray
    corner_names: tuple[str, ...]

    @property
    def n_markers(self) -> int:
        return self.squares[0] * self.squares[1] // 2

    def opencv(self) -> cv2.aruco.CharucoBoard:
        import cv2  # loaded here, when images are drawn or read: other commands skip its 30 ms

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, DICTIONARY))
        ids = np.arange(self.first_id, self.first_id + self.n_markers, dtype=np.int32)
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, MARKER_RATIO * self.square_m, dictionary, ids)

    def to_document(self) -> dict:
        return {
            "name": self.name,
            "squares": list(self.squares),
            "square": self.square_m,
            "first_id": self.first_id,
            "pose": {
                "xyz": [float(v) + 0.0 for v in self.T_F_B[:3, 3]],
                "rpy": [float(v) + 0.0 for v in rpy_from_rotation(self.T_F_B[:3, :3])],
            },
            "corners": list(self.corner_names),
        }
