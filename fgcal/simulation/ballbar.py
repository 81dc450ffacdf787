"""Ballbar cells: a telescoping bar between a ball on the flange and a fixed pivot reads the
distance between their centres. Each reading puts the ball at a random length within the
bar's travel and a random direction above the pivot's plane, the flange pointing down within
``max_tilt`` with a random spin, reached by inverse kinematics on the true robot. Readings
between configurations (``between_configurations``) put the ball at a random point of a
sphere, then at a random length in a random direction from there: two configurations each."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..data.dataset import write_csv
from .cell import Cell
from .touch import reach_all

MIN_ELEVATION_RAD = np.deg2rad(10.0)  # the bar stays clear of the pivot's mounting plate


def ballbar_design(
    cell: Cell, true_params: np.ndarray, design_rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Configurations (N, n), the pivot of each reading and the true distance (m)."""
    bar = cell.ballbar
    if not bar.names:
        return np.zeros((0, cell.robot.n_joints)), [], np.zeros(0)
    order = [k for k in range(len(bar.names)) for _ in range(bar.readings_per_pivot)]
    order = np.array([order[i] for i in design_rng.permutation(len(order))])
    length = design_rng.uniform(*bar.length_m, len(order))
    azimuth = design_rng.uniform(-np.pi, np.pi, len(order))
    elevation = np.arcsin(design_rng.uniform(np.sin(MIN_ELEVATION_RAD), 1.0, len(order)))
    direction = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    positions = bar.pivots[order] + length[:, None] * direction
    q = reach_all(
        cell, true_params, positions, bar.ball, bar.max_tilt_rad, design_rng, "ballbar.pivots",
        lambda pending: f"pivot {bar.names[order[pending[0]]]!r} with the bar's travel puts the ball out of the "
        "robot's reach", progress,
    )  # fmt: skip
    return q, [bar.names[k] for k in order], length


def ballbar_file_design(
    cell: Cell, path: Path, true_params: np.ndarray
) -> tuple[np.ndarray, list[str], np.ndarray, list[str]]:
    """The readings of a CSV (``config, q1..qn, pivot``, as fgcal plan writes it): the true
    robot at the file's joints, the true distance from its ball to the pivot; configurations,
    pivots, distances, and the configurations left out (the distance beyond the bar's travel)."""
    from ..core.errors import InputError
    from ..core.se3 import transform_points
    from .design import labelled_file

    robot, bar = cell.robot, cell.ballbar
    q, names, configs = labelled_file(path, cell, "pivot", bar.names)
    ball = transform_points(robot.fk(q, robot.parameter_dict(true_params), tip=cell.tip), bar.ball)
    length = np.linalg.norm(ball - bar.pivots[[bar.names.index(n) for n in names]], axis=1)
    inside = (length >= bar.length_m[0]) & (length <= bar.length_m[1])
    left_out = [configs[i] for i in np.flatnonzero(~inside)]
    if not inside.any():
        raise InputError(path, None, "the true robot puts the ball within the bar's travel at none of them")
    return q[inside], [n for n, ok in zip(names, inside, strict=True) if ok], length[inside], left_out


def pairs_design(
    cell: Cell, true_params: np.ndarray, design_rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> np.ndarray:
    """Configurations (2 P, n) of the readings between configurations: rows 2i and 2i+1 are
    the two ends of reading i."""
    bar = cell.ballbar
    radius = bar.pairs_radius_m * np.cbrt(design_rng.uniform(0.0, 1.0, bar.pairs))
    first = bar.pairs_centre + radius[:, None] * _directions(design_rng, bar.pairs)
    length = design_rng.uniform(*bar.length_m, bar.pairs)
    second = first + length[:, None] * _directions(design_rng, bar.pairs)
    positions = np.stack([first, second], axis=1).reshape(-1, 3)
    return reach_all(
        cell, true_params, positions, bar.ball, bar.max_tilt_rad, design_rng, "ballbar.between_configurations",
        lambda pending: "the sphere and the bar's travel put the ball out of the robot's reach", progress,
    )  # fmt: skip


def _directions(rng: np.random.Generator, count: int) -> np.ndarray:
    v = rng.normal(size=(count, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def write_pairs_table(
    out: Path, cell: Cell, config_ids: list[str], true_positions: np.ndarray, rng: np.random.Generator
) -> dict[str, int]:
    """tool_distances.csv: rows 2i and 2i+1 of ``true_positions`` (the true ball, W) are one
    reading's ends; the true distance plus the gauge's noise. The noise goes to truth/."""
    ends = true_positions.reshape(-1, 2, 3)
    true = np.linalg.norm(ends[:, 0] - ends[:, 1], axis=1)
    noise = rng.normal(0.0, cell.distance_sigma_m, len(true))
    ids = np.array(config_ids).reshape(-1, 2)
    write_csv(
        out / "tool_distances.csv",
        ["config_a", "config_b", "distance"],
        [[a, b, float(d + n)] for (a, b), d, n in zip(ids, true, noise, strict=True)],
    )
    write_csv(
        out / "truth" / "tool_distances_noise.csv",
        ["config_a", "config_b", "distance"],
        [[a, b, float(n)] for (a, b), n in zip(ids, noise, strict=True)],
    )
    return {"tool_distances": len(true)}


def write_ballbar_table(
    out: Path, cell: Cell, config_ids: list[str], pivots: list[str], lengths: np.ndarray, rng: np.random.Generator
) -> dict[str, int]:
    """distances.csv (each reading with the bar's noise); the noise goes to truth/."""
    noise = rng.normal(0.0, cell.distance_sigma_m, len(lengths))
    write_csv(
        out / "distances.csv",
        ["config", "pivot", "distance"],
        [[c, p, float(d + n)] for c, p, d, n in zip(config_ids, pivots, lengths, noise, strict=True)],
    )
    write_csv(
        out / "truth" / "distances_noise.csv",
        ["config", "pivot", "distance"],
        [[c, p, float(n)] for c, p, n in zip(config_ids, pivots, noise, strict=True)],
    )
    return {"distances": len(lengths)}
