"""Static-camera (eye-to-hand) cells: a camera fixed in the cell watches a board on the
flange. Configurations are drawn uniformly within the joint limits and kept where the true
camera sees the whole board (inside the image, in front of the camera, its face towards the
camera within ``max_view_angle``), thinned to N by greedy max-min distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.se3 import inverse, transform_points
from ..data.dataset import write_csv
from .cell import Cell
from .design import View, max_min_selection, uniform_configurations

DRAWS = 200  # random configurations drawn per wanted one before the board is declared unseen


def board_in_camera(cell: Cell, q: np.ndarray, true_params: dict[str, float]) -> np.ndarray:
    """T_C_B (N, 4, 4): the board's pose in the camera at each configuration, on the true robot."""
    setup = cell.static_camera
    return inverse(setup.pose) @ cell.robot.fk(q, true_params, tip=cell.tip) @ setup.board_mount


def board_seen(cell: Cell, T_C_B: np.ndarray) -> np.ndarray:
    """(N,) whether the camera sees the whole board at each of its poses T_C_B (N, 4, 4): its
    face (+z) towards the camera within ``max_view_angle`` of the line of sight, every corner
    in front of the camera and inside the image."""
    setup = cell.static_camera
    sight = T_C_B[:, :3, 3] / np.linalg.norm(T_C_B[:, :3, 3], axis=1)[:, None]
    facing = -np.sum(T_C_B[:, :3, 2] * sight, axis=1) >= np.cos(setup.max_view_angle_rad)
    seen = np.zeros(len(T_C_B), dtype=bool)
    for i in np.flatnonzero(facing):
        seen[i] = setup.camera.sees(transform_points(T_C_B[i], setup.board_points))
    return seen


def static_camera_design(cell: Cell, true_params: dict[str, float], rng: np.random.Generator) -> list[View]:
    wanted = cell.design.n_configurations
    pool = uniform_configurations(cell.robot, DRAWS * wanted, rng)
    seen = list(np.flatnonzero(board_seen(cell, board_in_camera(cell, pool, true_params))))
    if len(seen) < wanted:
        raise InputError(
            cell.source,
            "static_camera",
            f"the camera sees the whole board in {len(seen)} of {len(pool)} random configurations, fewer than "
            f"the {wanted} wanted: move the camera, or allow a larger max_view_angle",
        )
    visible = pool[seen]
    return [View(visible[i], None, ()) for i in max_min_selection(visible, cell.robot.limits, wanted, rng)]


def write_static_camera_tables(
    out: Path,
    cell: Cell,
    q: np.ndarray,
    config_ids: list[str],
    true_params: dict[str, float],
    rng: np.random.Generator,
) -> dict[str, int]:
    """points.csv (the board's corners in its frame) and pixels.csv (with the pixel noise);
    the noise goes to truth/."""
    setup = cell.static_camera
    write_csv(
        out / "points.csv",
        ["point", "object", "side", "x", "y", "z"],
        [[n, "board", "+z", *map(float, p)] for n, p in zip(setup.point_names, setup.board_points, strict=True)],
    )
    rows, noise_rows = [], []
    for cid, T in zip(config_ids, board_in_camera(cell, q, true_params), strict=True):
        pixels = setup.camera.project(transform_points(T, setup.board_points))
        noise = rng.normal(0.0, cell.pixel_sigma_px, pixels.shape)
        for name, px, n in zip(setup.point_names, pixels, noise, strict=True):
            rows.append([cid, name, *map(float, px + n)])
            noise_rows.append([cid, name, *map(float, n)])
    write_csv(out / "pixels.csv", ["config", "point", "u", "v"], rows)
    write_csv(out / "truth" / "pixels_noise.csv", ["config", "point", "u", "v"], noise_rows)
    return {"pixels": len(rows)}
