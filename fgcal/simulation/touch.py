"""Touch cells: the true robot puts its probe into each fixed point from many directions.

Each touch is a flange pose whose probe centre sits at the point (plus the seating noise:
where the ball settles, and the robot's repeatability), the probe approaching from above
within ``max_tilt`` in a random direction with a random spin about the approach, reached by
inverse kinematics on the true robot, so that the recorded joint angles are those at which
the real robot would be seated.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.console import step
from ..core.errors import InputError
from ..core.se3 import pose, so3_exp
from ..data.dataset import write_csv
from .cell import Cell
from .ik import solve_ik

STARTS = 8  # IK starts per touch, from random configurations


def approach_rotation(max_tilt_rad: float, rng: np.random.Generator) -> np.ndarray:
    """A flange orientation whose z axis (the probe's axis) points down within ``max_tilt``
    of the vertical, uniformly over that cap, with a uniform spin about it."""
    tilt = np.arccos(rng.uniform(np.cos(max_tilt_rad), 1.0))
    azimuth, spin = rng.uniform(-np.pi, np.pi, 2)
    down = np.diag([1.0, -1.0, -1.0])  # z along -z of W
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    return so3_exp(tilt * axis) @ down @ so3_exp(np.array([0.0, 0.0, spin]))


def touch_design(
    cell: Cell,
    true_params: np.ndarray,
    design_rng: np.random.Generator,
    noise_rng: np.random.Generator,
    progress: Callable[[str], None] | None = None,
) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Configurations (N, n) of the touches, the point each touches, and its seating noise (N, 3)
    (m): ``touches_per_point`` touches of every point, in a shuffled order."""
    touch = cell.touch
    order = [k for k in range(len(touch.names)) for _ in range(touch.touches_per_point)]
    order = [order[i] for i in design_rng.permutation(len(order))]
    noise = noise_rng.normal(0.0, cell.touch_sigma_m, (len(order), 3))
    positions = touch.points[order] + noise
    q = reach_all(
        cell, true_params, positions, touch.probe, touch.max_tilt_rad, design_rng, "touch.points",
        lambda pending: f"point {touch.names[order[pending[0]]]!r} is out of the robot's reach with the probe "
        "within max_tilt of vertical", progress,
    )  # fmt: skip
    return q, [touch.names[k] for k in order], noise


def touch_file_design(
    cell: Cell, path: Path, true_params: np.ndarray, design_rng: np.random.Generator, noise_rng: np.random.Generator
) -> tuple[np.ndarray, list[str], np.ndarray, list[str]]:
    """The touches of a CSV (``config, q1..qn, point``, as fgcal plan writes it): each seats
    the true robot's probe in its point (plus the seating noise) with the flange's orientation
    the nominal model has at the file's joints, by inverse kinematics from those joints (then
    from random starts); configurations, points, seating noise, and the configurations left
    out (not reached on the true robot)."""
    from .design import labelled_file

    robot, touch = cell.robot, cell.touch
    q_file, names, configs = labelled_file(path, cell, "point", touch.names)
    which = np.array([touch.names.index(name) for name in names])
    noise = noise_rng.normal(0.0, cell.touch_sigma_m, (len(names), 3))
    R = robot.fk(q_file, tip=cell.tip)[:, :3, :3]  # the nominal orientation the plan chose
    centres = touch.points[which] + noise
    targets = np.array([pose(R_i, c - R_i @ touch.probe) for c, R_i in zip(centres, R, strict=True)])
    q, solved = solve_ik(robot, true_params, targets, q_file, frame=cell.tip, freeze_converged=True)
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    for _ in range(STARTS):
        left = np.flatnonzero(~solved)
        if not len(left):
            break
        start = design_rng.uniform(np.maximum(low, -np.pi), np.minimum(high, np.pi), (len(left), robot.n_joints))
        q_try, ok = solve_ik(robot, true_params, targets[left], start, frame=cell.tip, freeze_converged=True)
        q[left[ok]], solved[left[ok]] = q_try[ok], True
    left_out = [configs[i] for i in np.flatnonzero(~solved)]
    if not solved.any():
        raise InputError(path, None, "the true robot seats its probe at none of the configurations")
    return q[solved], [names[i] for i in np.flatnonzero(solved)], noise[solved], left_out


ROUNDS = 20  # rounds of new orientations for the positions not reached yet
NOTHING_REACHED_ROUNDS = 2  # rounds without a single position reached after which the design stops
# Rounds after which a design with more than half its positions unreached stops (the bundled
# cells have a few percent left after one round; their last hard positions may take ten more).
MOSTLY_UNREACHED_ROUNDS = 3
PROGRESS_S = 5.0  # seconds between progress lines


def reach_all(
    cell: Cell,
    true_params: np.ndarray,
    positions: np.ndarray,
    tool_point: np.ndarray,
    max_tilt_rad: float,
    rng: np.random.Generator,
    field: str,
    unreachable: Callable[[np.ndarray], str],
    progress: Callable[[str], None] | None = None,
) -> np.ndarray:
    """Configurations (N, n) of the true robot that put ``tool_point`` (flange frame) at each
    of ``positions`` (W), the flange's z axis down within ``max_tilt_rad``, by inverse
    kinematics from random starts; or an error on the cell's ``field`` saying which it could
    not reach (``unreachable(indices of the positions not reached)`` says why)."""
    robot = cell.robot
    base_origin, reach = robot.reach_m(true_params, cell.tip)
    beyond = np.flatnonzero(np.linalg.norm(positions - base_origin, axis=1) > reach + np.linalg.norm(tool_point))
    if len(beyond):  # no search: the arm is not that long
        raise InputError(
            cell.source, field, f"{len(beyond)} positions farther from the base than the arm's "
            f"{(reach + np.linalg.norm(tool_point)) * 1e3:.0f} mm reach: {unreachable(beyond)}",
        )  # fmt: skip
    q = np.zeros((len(positions), robot.n_joints))
    pending = np.arange(len(positions))
    rounds, started = 0, time.monotonic()
    said = started
    for rounds in range(1, ROUNDS + 1):
        R = np.array([approach_rotation(max_tilt_rad, rng) for _ in pending])
        targets = np.array([pose(R_i, positions[i] - R_i @ tool_point) for i, R_i in zip(pending, R, strict=True)])
        low, high = robot.limits[:, 0], robot.limits[:, 1]
        starts = rng.uniform(np.maximum(low, -np.pi), np.minimum(high, np.pi), (STARTS, len(pending), robot.n_joints))
        solved = np.zeros(len(pending), dtype=bool)
        for start in starts:
            left = ~solved
            if not left.any():
                break
            q_try, ok = solve_ik(robot, true_params, targets[left], start[left], frame=cell.tip, freeze_converged=True)
            rows = np.flatnonzero(left)[ok]
            q[pending[rows]] = q_try[ok]
            solved[rows] = True
        pending = pending[~solved]
        step(progress, "reaching positions", len(positions) - len(pending), len(positions))
        if not len(pending) or (rounds >= NOTHING_REACHED_ROUNDS and len(pending) == len(positions)):
            break  # all reached, or none: more rounds would not help
        if rounds >= MOSTLY_UNREACHED_ROUNDS and len(pending) > len(positions) / 2:
            break  # half the design out of reach is the geometry, not the luck of the draws
        if progress is not None and time.monotonic() - said >= PROGRESS_S:
            said = time.monotonic()
            progress(
                f"  reaching {len(positions)} positions: {len(pending)} left after round {rounds} of at most "
                f"{ROUNDS} ({time.monotonic() - started:.0f} s)"
            )
    if len(pending):
        raise InputError(
            cell.source, field, f"{len(pending)} positions unreachable after {rounds} rounds of orientations: "
            f"{unreachable(pending)}",
        )  # fmt: skip
    return q


def write_touch_tables(
    out: Path, cell: Cell, config_ids: list[str], points: list[str], noise: np.ndarray, rng: np.random.Generator
) -> dict[str, int]:
    """touch_points.csv and, when the drawing gives them, point_distances.csv (every pair of
    touched points, each distance with the spacing noise); the noise goes to truth/."""
    touch = cell.touch
    write_csv(out / "touch_points.csv", ["config", "point"], [[c, p] for c, p in zip(config_ids, points, strict=True)])
    write_csv(
        out / "truth" / "touch_points_noise.csv",
        ["config", "point", "x", "y", "z"],
        [[c, p, *map(float, n)] for c, p, n in zip(config_ids, points, noise, strict=True)],
    )
    counts = {"touch_points": len(points)}
    if touch.known_distances:
        rows, noise_rows = [], []
        touched = [k for k, name in enumerate(touch.names) if name in set(points)]  # a plan may leave one out
        for i, a in enumerate(touched):
            for b in touched[i + 1 :]:
                n = float(rng.normal(0.0, cell.spacing_sigma_m))
                distance = float(np.linalg.norm(touch.points[a] - touch.points[b]))
                rows.append([touch.names[a], touch.names[b], distance + n])
                noise_rows.append([touch.names[a], touch.names[b], n])
        write_csv(out / "point_distances.csv", ["point_a", "point_b", "distance"], rows)
        write_csv(out / "truth" / "point_distances_noise.csv", ["point_a", "point_b", "distance"], noise_rows)
        counts["point_distances"] = len(rows)
    return counts
