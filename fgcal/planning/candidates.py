"""Candidate configurations a cell can measure, on the nominal model (no truth needed).

- camera cells: random viewpoints onto random 2x2 blocks of grid points at the design's
  standoff and viewing angle, reached by IK, kept where the nominal camera sees the block;
- tracker: configurations drawn uniformly within the joint limits (the reflectors are
  taken to be visible: fgcal's cells do not model the tracker's line of sight).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import InputError
from ..simulation.cell import Cell
from ..simulation.design import random_block_requests, solve_views, uniform_configurations

# A candidate needs its block in view, not a pose to 1e-9: fewer IK iterations, more candidates.
IK_ITERATIONS, IK_TOL = 25, 1e-6


@dataclass
class Candidates:
    q: np.ndarray  # (M, n) rad
    blocks: list[str] | None  # camera cells: the label of the block each configuration sees
    points_F: np.ndarray | None  # (M, 4, 3) the block's points in F (m)


def camera_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` reachable configurations, each seeing a block with the nominal camera."""
    robot = cell.robot

    # IK on the rigid DH,s model (the gravity deflection does not change what is visible),
    # from two starts per viewpoint: more viewpoints for the same time than six starts.
    ik_cell = replace(cell, robot=robot.with_model("DH,s"))
    views = []
    rounds = 0
    while len(views) < count and rounds < 40:
        rounds += 1
        requests = random_block_requests(cell, max(256, int(1.4 * (count - len(views)))), rng)
        views += solve_views(
            ik_cell, requests, robot.fk_tool, rng, starts=2, iterations=IK_ITERATIONS, tol=IK_TOL, freeze_converged=True
        )
        if progress:
            progress(f"  candidates: {min(len(views), count)} of {count} reachable, visible configurations")
        if rounds >= 3 and not views:
            raise InputError(cell.source, "objects", "no reachable configuration sees any block of the objects")
    views = views[:count]
    if len(views) < count:
        raise InputError(cell.source, "objects", f"only {len(views)} reachable, visible configurations found")
    return Candidates(
        np.array([v.q for v in views]),
        [v.block[0].name for v in views],
        np.array([[p.position_F for p in v.block] for v in views]),
    )


def joint_space_candidates(cell: Cell, count: int, rng: np.random.Generator) -> Candidates:
    """``count`` configurations uniform within the joint limits (fgcal.simulation.design)."""
    return Candidates(uniform_configurations(cell.robot, count, rng), None, None)
