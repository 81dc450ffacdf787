"""Self-observation: cameras on a link of the robot (its torso) see checkerboards on its tips
(the hands). The truth: each camera's mounting and each board's pose off the drawing's (up to
``mounting_error``, a length and an angle). Configurations are drawn in the middle of the joints'
ranges (the joints the contacts hold, held) and kept where a true camera sees a whole board
(every corner in front of it and inside the image, the board's face towards it within
``max_view_angle``); each camera's pixels of each board it sees are measured, with the cell's
pixel noise."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.se3 import inverse, pose, rpy_from_rotation, so3_exp, transform_points
from ..data.dataset import board_corners, write_csv
from ..model import kinematics
from .cell import Cell

DRAWS = 40  # random configurations drawn per wanted view before the boards are declared unseen
MIDDLE = 0.7  # within this central fraction of each joint's range


@dataclass(frozen=True)
class ObservationTruth:
    mountings: np.ndarray  # (c, 4, 4) T_link_C
    boards: np.ndarray  # (b, 4, 4) T_tip_B

    def documents(self, cell: Cell) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        setup = cell.self_observation
        return dict(zip(setup.camera_names, self.mountings, strict=True)), dict(
            zip(setup.board_names, self.boards, strict=True)
        )


def observation_truth(cell: Cell, rng: np.random.Generator) -> ObservationTruth:
    setup = cell.self_observation

    def off(T: np.ndarray) -> np.ndarray:
        axis = rng.normal(size=3)
        turn = so3_exp(axis / np.linalg.norm(axis) * rng.uniform(0.0, setup.angle_error_rad))
        return T @ pose(turn, rng.uniform(-setup.length_error_m, setup.length_error_m, 3))

    return ObservationTruth(np.array([off(T) for T in setup.mountings]), np.array([off(T) for T in setup.poses]))


def _tip_name(joint: int) -> str:
    return f"link{joint}"


@dataclass(frozen=True)
class Views:
    q: np.ndarray  # (N, n)
    rows: list[tuple[int, str, str, str, np.ndarray]]  # (configuration, camera, board, point, pixel)
    noise: np.ndarray  # (P, 2) px


def observation_design(
    cell: Cell, true_params: np.ndarray, truth: ObservationTruth, design_rng: np.random.Generator,
    noise_rng: np.random.Generator,
) -> Views:  # fmt: skip
    """``views`` configurations at which a camera sees a whole board, and every such pixel."""
    setup = cell.self_observation
    # The cameras' links as tips of the robot (their frames), for the kinematics.
    links = sorted({j for j in setup.joints if j > 0})
    robot = replace(cell.robot, tips=(*cell.robot.tips, *((_tip_name(j), j - 1, np.eye(4)) for j in links)))
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    centre, half = (low + high) / 2, MIDDLE * (high - low) / 2
    q = design_rng.uniform(centre - half, centre + half, (DRAWS * setup.views, robot.n_joints))
    if cell.contact is not None:  # the joints the contacts hold, held here too
        q[:, list(cell.contact.held)] = cell.contact.held_at
    data = kinematics.forward(robot, true_params, q)
    boards = [board_corners(c, r, s) for (c, r), s in zip(setup.corners, setup.squares, strict=True)]
    seen = np.zeros((len(q), len(setup.camera_names), len(setup.board_names)), dtype=bool)
    T_C_B = {}
    for c, (joint, camera) in enumerate(zip(setup.joints, setup.cameras, strict=True)):
        link = (np.broadcast_to(robot.base_pose, (len(q), 4, 4)) if joint == 0
                else kinematics.frame_pose(robot, data, _tip_name(joint)))  # fmt: skip
        T_C_W = inverse(link @ truth.mountings[c])
        for k, tip in enumerate(setup.tips):
            T = T_C_W @ kinematics.frame_pose(robot, data, tip) @ truth.boards[k]
            sight = T[:, :3, 3] / np.linalg.norm(T[:, :3, 3], axis=1)[:, None]
            facing = -np.sum(T[:, :3, 2] * sight, axis=1) >= np.cos(setup.max_view_angle_rad)
            for i in np.flatnonzero(facing):
                seen[i, c, k] = camera.sees(transform_points(T[i], boards[k][0]))
            T_C_B[c, k] = T
    kept = np.flatnonzero(seen.any(axis=(1, 2)))[: setup.views]
    if len(kept) < setup.views:
        raise InputError(cell.source, "self_observation", f"a camera sees a whole board in {len(kept)} of {len(q)} "
                         f"random configurations, fewer than the {setup.views} wanted: aim the cameras at the hands' "
                         "workspace, or allow a larger max_view_angle")  # fmt: skip
    rows = []
    for j, i in enumerate(kept):
        for c, k in zip(*np.nonzero(seen[i]), strict=True):
            pixels = setup.cameras[c].project(transform_points(T_C_B[c, k][i], boards[k][0]))
            for name, pixel in zip(boards[k][1], pixels, strict=True):
                rows.append((j, setup.camera_names[c], setup.board_names[k], name, pixel))
    noise = noise_rng.normal(0.0, cell.pixel_sigma_px, (len(rows), 2))
    return Views(q[kept], rows, noise)


def write_observed_pixels(out: Path, views: Views, config_ids: list[str]) -> dict[str, int]:
    columns = ["config", "camera", "board", "point", "u", "v"]
    write_csv(
        out / "observed_pixels.csv",
        columns,
        [
            [config_ids[j], c, b, p, *map(float, z + n)]
            for (j, c, b, p, z), n in zip(views.rows, views.noise, strict=True)
        ],
    )
    write_csv(out / "truth" / "observed_pixels_noise.csv", columns,
              [[config_ids[j], c, b, p, *map(float, n)] for (j, c, b, p, _), n in zip(views.rows, views.noise,
                                                                                      strict=True)])  # fmt: skip
    return {"observed_pixels": len(views.rows)}


def observation_header(cell: Cell) -> dict:
    """dataset.yaml self_observation: the drawing's cameras and boards (SI)."""
    setup = cell.self_observation

    def pose_doc(T: np.ndarray) -> dict:
        return {"xyz": [float(v) for v in T[:3, 3]], "rpy": [float(v) for v in rpy_from_rotation(T[:3, :3])]}

    return {
        "cameras": {
            name: {"joint": joint, "mounting": pose_doc(T), **camera.to_document()}
            for name, joint, T, camera in zip(setup.camera_names, setup.joints, setup.mountings, setup.cameras,
                                              strict=True)
        },
        "boards": {
            name: {"tip": tip, "pose": pose_doc(T), "corners": list(corners), "square": float(square)}
            for name, tip, T, corners, square in zip(setup.board_names, setup.tips, setup.poses, setup.corners,
                                                     setup.squares, strict=True)
        },
    }  # fmt: skip
