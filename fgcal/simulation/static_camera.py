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


def static_camera_design(cell: Cell, true_params: dict[str, float], rng: np.random.Generator) -> list[View]:
    setup = cell.static_camera
    wanted = cell.design.n_configurations
    pool = uniform_configurations(cell.robot, DRAWS * wanted, rng)
    T_C_B = board_in_camera(cell, pool, true_params)
    seen = []
    for i, T in enumerate(T_C_B):
        points = transform_points(T, setup.board_points)
        # The board's face (+z) towards the camera: its normal against the line of sight.
        sight = T[:3, 3] / np.linalg.norm(T[:3, 3])
        facing = -float(T[:3, 2] @ sight) >= np.cos(setup.max_view_angle_rad)
        if facing and setup.camera.sees(points):
            seen.append(i)
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
