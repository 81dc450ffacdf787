"""Ballbar cells: a telescoping bar between a ball on the flange and a fixed pivot reads the
distance between their centres. Each reading puts the ball at a random length within the
bar's travel and a random direction above the pivot's plane, the flange pointing down within
``max_tilt`` with a random spin, reached by inverse kinematics on the true robot."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset import write_csv
from ..errors import InputError
from .cell import Cell
from .touch import ROUNDS, reach

MIN_ELEVATION_RAD = np.deg2rad(10.0)  # the bar stays clear of the pivot's mounting plate


def ballbar_design(
    cell: Cell, true_params: np.ndarray, design_rng: np.random.Generator
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Configurations (N, n), the pivot of each reading and the true distance (m)."""
    bar = cell.ballbar
    order = [k for k in range(len(bar.names)) for _ in range(bar.readings_per_pivot)]
    order = np.array([order[i] for i in design_rng.permutation(len(order))])
    length = design_rng.uniform(*bar.length_m, len(order))
    azimuth = design_rng.uniform(-np.pi, np.pi, len(order))
    elevation = np.arcsin(design_rng.uniform(np.sin(MIN_ELEVATION_RAD), 1.0, len(order)))
    direction = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    positions = bar.pivots[order] + length[:, None] * direction
    q, pending = reach(cell, true_params, positions, bar.ball, bar.max_tilt_rad, design_rng)
    if len(pending):
        raise InputError(
            cell.source,
            "ballbar.pivots",
            f"{len(pending)} ballbar positions unreachable after {ROUNDS} rounds of orientations: pivot "
            f"{bar.names[order[pending[0]]]!r} with the bar's travel puts the ball out of the robot's reach",
        )
    return q, [bar.names[k] for k in order], length


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
