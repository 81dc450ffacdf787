"""Designs of configurations: camera viewpoints onto 2x2 blocks of grid points, reached by
inverse kinematics on the nominal model and kept only where the true robot's camera sees
all four points.

- ``seed``: the seed paper's design: on every side, ``blocks_per_side`` blocks spread over
  the side, each seen from ``views_per_block`` configurations.
- ``space_filling``: many random viewpoints on random blocks of every side, reduced to N
  configurations by greedy max-min distance in normalised joint space, so that the
  configurations spread over the robot's joint space rather than cluster.
- a file (``fgcal plan``'s configurations.csv): exactly those configurations and blocks.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.console import step
from ..core.errors import InputError
from ..core.se3 import inverse, pose, transform_points
from ..model.robot import Robot
from .cell import Cell, GridPoint, Side
from .ik import solve_ik

# IK problems solved at once: each holds a few tens of kB of kinematics, so memory stays
# flat in the number of configurations, and the batches are still large enough to vectorise.
IK_CHUNK = 2048


@dataclass(frozen=True)
class View:
    """A configuration and the block of points its camera sees."""

    q: np.ndarray
    side: Side | None  # None, and no block, in a tracker cell
    block: tuple[GridPoint, ...]
    before: np.ndarray | None = None  # the joints it is approached from, when a file says (else the previous)
    config: str | None = None  # its id, when a file names it (a plan's: its pair_groups.csv names them)


def look_at(camera_position: np.ndarray, target: np.ndarray, roll_rad: np.ndarray | float) -> np.ndarray:
    """Camera poses T_W_C (..., 4, 4) with optical axis (z) from ``camera_position`` (..., 3)
    to ``target`` (..., 3), rolled by ``roll_rad`` about it."""
    z = target - camera_position
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    helper = np.where((np.abs(z[..., 2]) < 0.9)[..., None], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=-1)
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    zero, one = np.zeros_like(c), np.ones_like(c)
    roll = np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2)
    return pose(R @ roll, camera_position)


def _random_views(cell: Cell, requests: list[tuple[Side, list[GridPoint]]], rng: np.random.Generator) -> np.ndarray:
    """Camera poses (N, 4, 4), each at a random standoff, viewing angle and roll onto its
    block's centre; per request the draws are tilt, azimuth, standoff and roll, in that order."""
    design = cell.design
    centre = transform_points(
        cell.fixture_pose, np.array([np.mean([p.position_F for p in b], axis=0) for _, b in requests])
    )
    normal = np.array([side.normal_F for side, _ in requests]) @ cell.fixture_pose[:3, :3].T
    u = rng.random((len(requests), 4))
    # As Generator.uniform(low, high) draws: low + (high - low) * u, the same numbers.
    cos_max = np.cos(design.max_view_angle_rad)
    tilt = np.arccos(cos_max + (1.0 - cos_max) * u[:, 0])
    azimuth = -np.pi + (np.pi - -np.pi) * u[:, 1]
    standoff = design.standoff_m[0] + (design.standoff_m[1] - design.standoff_m[0]) * u[:, 2]
    roll = -np.pi + (np.pi - -np.pi) * u[:, 3]
    helper = np.where((np.abs(normal[:, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normal, e1)
    direction = np.cos(tilt)[:, None] * normal + np.sin(tilt)[:, None] * (
        np.cos(azimuth)[:, None] * e1 + np.sin(azimuth)[:, None] * e2
    )
    return look_at(centre + standoff[:, None] * direction, centre, roll)


def solve_views(
    cell: Cell,
    requests: list[tuple[Side, list[GridPoint]]],
    true_camera: Callable,
    rng: np.random.Generator,
    starts: int = 6,
    iterations: int = 80,
    tol: float = 1e-9,
    freeze_converged: bool = True,
    solved: Callable[[int, int], None] | None = None,
) -> list[View]:
    """IK for one random viewpoint per request (``iterations``, ``tol``: of the IK); keep
    the reachable, visible ones. Each start stops iterating once within ``tol`` (rad, m):
    ``freeze_converged=False`` iterates every start to the end, which moved the configurations
    by at most 3e-9 rad on the demo and took 0.9 s more of its 3.4 s CPU. Frozen, a request's
    later starts also stop once one has converged (only the first converged one is used).
    ``solved(done, total)`` hears of the IK starts solved."""
    robot: Robot = cell.robot
    nominal = robot.parameter_vector()
    if not requests:
        return []
    targets_C = _random_views(cell, requests, rng)
    T_target = targets_C @ inverse(robot.tool_pose)
    T_rep = np.repeat(T_target, starts, axis=0)
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    span_low, span_high = np.maximum(low, -np.pi), np.minimum(high, np.pi)
    q0 = rng.uniform(span_low, span_high, size=(len(T_rep), robot.n_joints))
    q, ok = np.empty_like(q0), np.empty(len(q0), dtype=bool)
    for first in range(0, len(q0), IK_CHUNK):
        chunk = slice(first, first + IK_CHUNK)
        q[chunk], ok[chunk] = solve_ik(
            robot, nominal, T_rep[chunk], q0[chunk], iterations=iterations, tol=tol, freeze_converged=freeze_converged,
            target_of=np.arange(len(q0))[chunk] // starts if freeze_converged else None,
        )  # fmt: skip
        if solved is not None:
            solved(min(first + IK_CHUNK, len(q0)), len(q0))
    # The first converged start of each request; one forward-kinematics pass for them all.
    first: dict[int, int] = {}
    for j in np.flatnonzero(ok):
        first.setdefault(int(j) // starts, int(j))
    if not first:
        return []
    T_W_C = true_camera(q[list(first.values())])
    views = []
    for (i, j), camera in zip(first.items(), T_W_C, strict=True):
        side, block = requests[i]
        if sees_block(cell, camera, block):
            views.append(View(q[j], side, tuple(block)))
    return views


def sees_block(cell: Cell, T_W_C: np.ndarray, block: Sequence[GridPoint]) -> bool:
    """Whether a camera at ``T_W_C`` sees every point of ``block``."""
    points_W = transform_points(cell.fixture_pose, np.array([p.position_F for p in block]))
    return bool(cell.camera.sees(transform_points(inverse(T_W_C), points_W)))


def random_block_requests(cell: Cell, count: int, rng: np.random.Generator) -> list[tuple[Side, list[GridPoint]]]:
    """``count`` (side, block) pairs: a random side, then a random block on it."""
    requests = []
    for _ in range(count):
        side = cell.sides[rng.integers(len(cell.sides))]
        requests.append((side, side.block(int(rng.integers(side.n_block_rows)), int(rng.integers(side.n_block_cols)))))
    return requests


def _spread_blocks(side: Side, count: int) -> list[tuple[int, int]]:
    """``count`` block corners spread over a side (along its diagonal and centre)."""
    rows, cols = side.n_block_rows, side.n_block_cols
    fractions = [0.5] if count == 1 else np.linspace(0.15, 0.85, count)
    corners = [
        (round(f * (rows - 1)), round((f if k % 2 == 0 else 1 - f) * (cols - 1))) for k, f in enumerate(fractions)
    ]
    return corners


def seed_design(cell: Cell, true_camera: Callable, rng: np.random.Generator, max_rounds: int = 20) -> list[View]:
    """The seed's design: per side, blocks_per_side blocks, each from views_per_block views."""
    design = cell.design
    wanted = [
        (side, side.block(*corner))
        for side in cell.sides
        for corner in _spread_blocks(side, design.blocks_per_side)
        for _ in range(design.views_per_block)
    ]
    views: list[View | None] = [None] * len(wanted)
    for round_ in range(max_rounds):
        missing = [i for i, v in enumerate(views) if v is None]
        if not missing:
            break
        solved = solve_views(cell, [wanted[i] for i in missing], true_camera, rng)
        if round_ + 1 >= NOTHING_REACHABLE_ROUNDS and not solved and len(missing) == len(wanted):
            raise _unreachable(cell, round_ + 1, len(wanted))
        solved_by_key: dict[str, list[View]] = {}
        for v in solved:
            solved_by_key.setdefault(v.block[0].name, []).append(v)
        for i in missing:
            pool = solved_by_key.get(wanted[i][1][0].name)
            if pool:
                views[i] = pool.pop()
    missing = [i for i, v in enumerate(views) if v is None]
    if missing:
        side, block = wanted[missing[0]]
        raise InputError(
            cell.source,
            "objects",
            f"no reachable, visible viewpoint found for block {block[0].name} on {side.obj}{side.side} "
            f"after {max_rounds} rounds: move the object or widen standoff/max_view_angle",
        )
    return [v for v in views if v is not None]


def space_filling_design(
    cell: Cell,
    true_camera: Callable,
    rng: np.random.Generator,
    oversample: int = 3,
    progress: Callable[[str], None] | None = None,
) -> list[View]:
    """N configurations: random reachable views, thinned by greedy max-min joint distance."""
    n_wanted = cell.design.n_configurations
    pool: list[View] = []
    rounds = 0
    started = last = round_started = time.monotonic()

    def solved(done: int, total: int) -> None:  # a bar on a terminal; a line every 10 s, with an estimate
        nonlocal last
        step(progress, f"design round {rounds}: IK starts", done, total)
        now = time.monotonic()
        if progress and now - last > 10 and done < total:
            last = now
            left = (now - round_started) / done * (total - done)
            progress(f"  space-filling design: round {rounds}, {done} of {total} IK starts ({now - started:.0f} s, "
                     f"about {left:.0f} s left in this round)")  # fmt: skip

    while len(pool) < oversample * n_wanted and rounds < 30:
        rounds += 1
        requests = random_block_requests(cell, max(64, oversample * n_wanted - len(pool)), rng)
        round_started = time.monotonic()
        pool += solve_views(cell, requests, true_camera, rng, solved=solved)
        step(progress, f"design round {rounds}: IK starts", 1, 1)  # the round's bar closes
        step(progress, "design: candidate configurations", min(len(pool), oversample * n_wanted), oversample * n_wanted)
        if not pool and rounds >= NOTHING_REACHABLE_ROUNDS:
            raise _unreachable(cell, rounds, len(requests))
        if progress:
            elapsed = time.monotonic() - started
            left = elapsed * max(0, oversample * n_wanted - len(pool)) / max(len(pool), 1)
            progress(
                f"  space-filling design: {len(pool)} candidate configurations, {oversample * n_wanted} wanted "
                f"({elapsed:.0f} s" + (f", about {left:.0f} s left)" if len(pool) < oversample * n_wanted else ")")
            )
    if len(pool) < n_wanted:
        raise InputError(
            cell.source,
            "design.n_configurations",
            f"only {len(pool)} reachable, visible configurations found for {n_wanted} wanted",
        )
    return [pool[i] for i in max_min_selection(np.array([v.q for v in pool]), cell.robot.limits, n_wanted, rng)]


def uniform_configurations(robot: Robot, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, n) configurations uniform within the joint limits, revolute joints within
    +-pi (further turns repeat the same poses)."""
    low, high = robot.limits[:, 0].copy(), robot.limits[:, 1].copy()
    revolute = ~robot.prismatic
    low[revolute], high[revolute] = np.maximum(low[revolute], -np.pi), np.minimum(high[revolute], np.pi)
    return rng.uniform(low, high, (count, robot.n_joints))


def joint_space_design(cell: Cell, rng: np.random.Generator, oversample: int = 3) -> list[View]:
    """A tracker cell's space-filling design: configurations uniform within the joint limits,
    thinned to N by greedy max-min distance."""
    robot = cell.robot
    n_wanted = cell.design.n_configurations
    pool = uniform_configurations(robot, oversample * n_wanted, rng)
    return [View(pool[i], None, ()) for i in max_min_selection(pool, robot.limits, n_wanted, rng)]


# Rounds of random viewpoints without a single reachable, visible one after which the cell is
# declared unreachable (each round tries every wanted view from six IK starts).
NOTHING_REACHABLE_ROUNDS = 2


def _unreachable(cell: Cell, rounds: int, per_round: int) -> InputError:
    return InputError(
        cell.source,
        "objects",
        f"no reachable, visible viewpoint on any object in {rounds} rounds of {per_round} random views: the "
        "objects are out of the robot's reach where the fixture and objects put them, or the camera cannot see "
        "a block from the design's standoff and max_view_angle",
    )


def max_min_selection(q: np.ndarray, limits: np.ndarray, count: int, rng: np.random.Generator) -> list[int]:
    """Greedy farthest-point selection of ``count`` rows of q, normalised by joint range."""
    # Columns of the transposed pool: one contiguous pass per joint, squared distances (the
    # same order as distances), about 20x faster than a norm over rows; the same choice.
    x = np.ascontiguousarray((q / (limits[:, 1] - limits[:, 0])).T)
    chosen = [int(rng.integers(x.shape[1]))]
    scratch = np.empty(x.shape[1])

    def squared_distance(i: int) -> np.ndarray:
        total = np.zeros(x.shape[1])
        for column in x:
            np.subtract(column, column[i], out=scratch)
            total += scratch * scratch
        return total

    dist = squared_distance(chosen[0])
    for _ in range(count - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        np.minimum(dist, squared_distance(nxt), out=dist)
    return chosen


def blocks_by_label(cell: Cell) -> dict[str, tuple[Side, list[GridPoint]]]:
    """Every 2x2 block of the cell by its label: the name of its first grid point."""
    return {
        side.points[r][c].name: (side, side.block(r, c))
        for side in cell.sides
        for r in range(side.n_block_rows)
        for c in range(side.n_block_cols)
    }


def file_design(cell: Cell, path: Path, true_camera: Callable) -> tuple[list[View], list[str]]:
    """Exactly the configurations of a CSV (``config, q1..qn, block``; rad; ``block`` the
    label of the block the camera looks at, as fgcal plan writes it; no ``block`` in a
    tracker cell; ``before_q1..before_qn``: each one's approach point). Configurations whose
    block the simulated true camera does not see are left out; their ids are returned."""
    from ..data.dataset import approach_columns, line_numbers, parse_numbers, read_csv

    robot = cell.robot
    joints = [f"q{i}" for i in range(1, robot.n_joints + 1)]
    header, body = read_csv(path, ["config", *joints, *(["block"] if cell.camera is not None else [])])
    extra = [c for c in header if c.startswith("q") and c[1:].isdigit() and c not in joints]
    if extra:
        raise InputError(
            path, "header", f"column {extra[0]}: {robot.name} has {robot.n_joints} joints (q1..q{robot.n_joints})"
        )
    if not body:
        raise InputError(path, None, "no configurations")
    q = parse_numbers(path, header, body, joints, "angle", 1.0)
    before = approach_columns(path, header, body, robot.n_joints, 1.0)
    outside = np.flatnonzero(np.any((q < robot.limits[:, 0] - 1e-9) | (q > robot.limits[:, 1] + 1e-9), axis=1))
    if outside.size:
        raise InputError(path, f"line {line_numbers(body)[outside[0]]}", f"joint values outside {robot.name}'s limits")
    blocks = blocks_by_label(cell)
    T_W_C = true_camera(q) if cell.camera is not None else None
    views, unseen = [], []
    for i, row in enumerate(body):
        config = row[header.index("config")].strip()
        approach = before[i] if np.all(np.isfinite(before[i])) else None
        if cell.camera is None:  # a tracker cell: nothing to see
            views.append(View(q[i], None, (), approach, config))
            continue
        label = row[header.index("block")].strip()
        if label not in blocks:
            raise InputError(path, f"line {line_numbers(body)[i]}, column block", f"no block {label!r} in {cell.name}")
        side, block = blocks[label]
        if sees_block(cell, T_W_C[i], block):
            views.append(View(q[i], side, tuple(block), approach, config))
        else:
            unseen.append(config)
    if not views:
        raise InputError(path, None, "the simulated camera sees its block at none of the configurations")
    return views, unseen


def labelled_file(path: Path, cell: Cell, column: str, known: Sequence[str]) -> tuple[np.ndarray, list[str], list[str]]:
    """A plan's CSV of labelled configurations (``config, q1..qn, COLUMN``, as fgcal plan writes a
    touch or ballbar plan): the joints (N, n), each row's label (one of ``known``, the cell's) and
    each row's configuration id."""
    from ..data.dataset import line_numbers, parse_numbers, read_csv

    joints = [f"q{i}" for i in range(1, cell.robot.n_joints + 1)]
    header, body = read_csv(path, ["config", *joints, column])
    if not body:
        raise InputError(path, None, "no configurations")
    q = parse_numbers(path, header, body, joints, "angle", 1.0)
    labels = [row[header.index(column)].strip() for row in body]
    for line, label in zip(line_numbers(body), labels, strict=True):
        if label not in known:
            raise InputError(path, f"line {line}, column {column}", f"no {column} {label!r} in {cell.name}")
    return q, labels, [row[header.index("config")].strip() for row in body]
