"""What ``fgcal plan`` models of a formulation's measurements (``Formulation.planning``).

A :class:`Planning` says how the formulation's candidate configurations are drawn from a cell
and what each candidate measures: whitened Jacobian rows on the parameters and on the
formulation's auxiliary unknowns, their labels and prior sigmas, the scored point and the
gauge of the score. fgcal.planning calls only this protocol.

- :class:`FlangeCamera` (pairs, projection): candidates see a 2x2 block of the calibration
  objects' grid points; the rows are the block's four points in the camera frame,
  ``p_C = R_C_W (T_W_F p_F - t_W_C)``, sigma the cell's camera point sigma; auxiliary: the
  fixture translation (the relative pairs do not see it), and its rotation when the
  formulation estimates it. The scored point is the mean block point in the camera frame.
- :class:`Reflectors` (tracker): candidates uniform in joint space; the rows are the
  reflectors in the tracker frame, ``p_T = T_T_W T_W_n(q) s_t``, sigma the cell's tracker
  sigma; auxiliary: the tracker pose and the reflector positions s_t. The scored point is the
  first reflector.

A point pair is the difference of two such point measurements, so the absolute points in
an unknown fixture frame carry the same information about the robot as the pairs that
connect every image (up to the translation the pairs never see).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import InputError
from ..core.se3 import inverse, pose, skew, transform_points
from ..model import kinematics
from ..model.robot import Robot
from ..simulation.cell import Cell
from ..simulation.design import random_block_requests, solve_views, uniform_configurations
from ..simulation.ik import solve_ik
from ..simulation.static_camera import board_seen
from ..simulation.touch import approach_rotation

PRIOR_SIGMA_AUX = {"translation": 1.0, "rotation": 1.0, "reflector": 0.1}  # m, rad, m: weak priors
# A candidate needs its block in view, not a pose to 1e-9: fewer IK iterations, more candidates.
IK_ITERATIONS, IK_TOL = 25, 1e-6


@dataclass
class Candidates:
    q: np.ndarray  # (M, n) rad
    blocks: list[str] | None  # camera cells: the label of the block each configuration sees
    points_F: np.ndarray | None  # (M, 4, 3) the block's points in F (m)
    # Why draws were not kept as candidates: {reason: how many}; a plan reports it.
    discarded: dict[str, int] = field(default_factory=dict)
    # (M, k) which of the k things a candidate would measure the instrument sees (the rows of
    # the others are zero: not measured); None: all of them.
    seen: np.ndarray | None = None
    seen_label: str = ""  # what the k things are ("reflectors")
    label_column: str = "block"  # configurations.csv's column of ``blocks`` (the block seen, the point touched)
    # A label chosen must be chosen this often (a point touched once is not calibrated), or not at all.
    min_per_label: int = 1
    # The configurations over which accuracy counts (None: the candidates): the workspace,
    # where the candidates are only those the instrument can measure.
    workspace: np.ndarray | None = None


@dataclass(frozen=True)
class PlanRows:
    """What the candidates measure: rows whitened by the measurement sigma."""

    params: np.ndarray  # (M, r, m) on the parameters ``names``
    aux: np.ndarray  # (M, r, a) on the auxiliary unknowns
    aux_labels: list[str]  # (a,)
    aux_sigma: np.ndarray  # (a,) their weak prior sigmas (m, rad)
    sigma_m: float  # the measurement sigma the rows are whitened by (in ``unit``)
    frame: str  # the scored point's frame
    point: np.ndarray  # (3,) the scored point in that frame
    gauge: str  # what the score removes first: none, translation or rigid
    unit: str = "m"  # of the measurement sigma: m, or px
    # Whitened rows every design has, on the auxiliary unknowns alone (a drawing's known
    # distances between touched points); None: none.
    fixed: np.ndarray | None = None
    # Pairs: what the exact pair groups need (fgcal.planning.groups); None: no groups.
    grouping: PairRows | None = None


# Where a plan writes the groups it chose, and the calibration config's setting that reads them.
PAIR_GROUPS_FILE = "pair_groups.csv"


def pair_groups_setting(path: str) -> dict:
    """The calibration config's fields naming a pair groups file (pairs.groups)."""
    return {"pairs": {"groups": path}}


@dataclass(frozen=True)
class PairRows:
    """A pair formulation's rows before its groups: a group of images loses the common
    translation, in W, of all its points (formulations.pairs: the contrasts cancel it), so its
    information is ``sum_j J_j^T J_j - U^T U / n`` with ``U = sum_j R_W_C,j sum_points J_j,point``
    (the camera-frame rows turned into W; n the group's points)."""

    params: np.ndarray  # (M, r, m) whitened, ungrouped, on the parameters
    aux: np.ndarray  # (M, r, a) on the auxiliary unknowns
    turn: np.ndarray  # (M, 3, 3) R_W_C: the camera frame of each candidate's rows into W
    size: int  # images per group (pairs.group_images)


class Planning(ABC):
    """How fgcal plan draws a formulation's candidates and what each of them measures."""

    @abstractmethod
    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        """``count`` candidate configurations of the cell (seeded by ``rng``), on the nominal model."""

    @abstractmethod
    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        """The whitened rows of every candidate (``data``: the kinematics at ``cand.q``) on the
        parameters ``names`` and on the auxiliary unknowns."""


@dataclass(frozen=True)
class FlangeCamera(Planning):
    """A camera on the flange seeing the cell's calibration objects (pairs, projection)."""

    rotation: bool  # the fixture's orientation in W is an unknown (its position always is)
    # Pairs: the images fall into groups of this many at random, each group with a common
    # position of its own that its pairs do not see (None: one fixture position for all images).
    group_images: int | None = None

    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        return camera_candidates(cell, count, rng, progress=progress)

    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        J_p, J_aux, p_C = _camera_rows(robot, data, cell, cand, names, self.rotation)
        sigma = cell.camera_point_sigma_m
        grouping = None
        if self.group_images is not None:
            turn = kinematics.frame_pose(robot, data, "tool")[:, :3, :3]
            grouping = PairRows(J_p / sigma, J_aux / sigma, turn, self.group_images)
            J_p, J_aux = _grouped(J_p, J_aux, p_C, self.group_images)
        labels = (["fixture.rx", "fixture.ry", "fixture.rz"] if self.rotation else []) + [
            "fixture.tx",
            "fixture.ty",
            "fixture.tz",
        ]
        aux_sigma = ([PRIOR_SIGMA_AUX["rotation"]] * 3 if self.rotation else []) + [PRIOR_SIGMA_AUX["translation"]] * 3
        return PlanRows(
            params=J_p / sigma,
            aux=J_aux / sigma,
            aux_labels=labels,
            aux_sigma=np.array(aux_sigma),
            sigma_m=sigma,
            frame="tool",
            point=p_C.reshape(-1, 3).mean(axis=0),
            gauge="rigid" if self.rotation else "translation",
            grouping=grouping,
        )


@dataclass(frozen=True)
class Reflectors(Planning):
    """A laser tracker measuring reflectors on the flange or a tree's tips (tracker)."""

    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        return joint_space_candidates(cell, count, rng, progress=progress)

    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        J_p, J_aux = _tracker_rows(robot, data, cell, cand, names)
        if cand.seen is not None:  # a reflector the tracker does not see is not measured
            mask = np.repeat(cand.seen, 3, axis=1)[:, :, None]
            J_p, J_aux = J_p * mask, J_aux * mask
        sigma = cell.tracker_sigma_m
        n_targets = len(cell.tracker_targets)
        labels = ["tracker.rx", "tracker.ry", "tracker.rz", "tracker.tx", "tracker.ty", "tracker.tz"]
        labels += [f"reflector{t + 1}.{a}" for t in range(n_targets) for a in "xyz"]
        aux_sigma = [PRIOR_SIGMA_AUX["rotation"]] * 3 + [PRIOR_SIGMA_AUX["translation"]] * 3
        aux_sigma += [PRIOR_SIGMA_AUX["reflector"]] * (3 * n_targets)
        return PlanRows(
            params=J_p / sigma,
            aux=J_aux / sigma,
            aux_labels=labels,
            aux_sigma=np.array(aux_sigma),
            sigma_m=sigma,
            frame=cell.tracker_target_tips[0] if cell.tracker_target_tips else "flange",
            point=cell.tracker_targets[0],
            gauge="none",
        )


@dataclass(frozen=True)
class StaticBoard(Planning):
    """A camera fixed in the cell watching a board on the flange (static_camera)."""

    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        return board_candidates(cell, count, rng, progress=progress)

    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        setup = cell.static_camera
        J_p, J_aux = _board_rows(robot, data, cell, names)
        sigma = cell.pixel_sigma_px
        labels = [f"{what}.{a}" for what in ("static_camera", "board") for a in ("rx", "ry", "rz", "tx", "ty", "tz")]
        aux_sigma = ([PRIOR_SIGMA_AUX["rotation"]] * 3 + [PRIOR_SIGMA_AUX["translation"]] * 3) * 2
        return PlanRows(
            params=J_p / sigma,
            aux=J_aux / sigma,
            aux_labels=labels,
            aux_sigma=np.array(aux_sigma),
            sigma_m=sigma,
            frame=cell.tip,
            point=setup.board_mount[:3, 3].copy(),
            gauge="rigid",
            unit="px",
        )


@dataclass(frozen=True)
class ProbeTouches(Planning):
    """A probe on the flange seated in fixed points from above (touch): the rows are the
    probe's centre in W, ``T_W_n(q) s - a_k = 0``, sigma the cell's touch sigma; auxiliary: the
    probe s and the points a_k; the drawing's known distances are rows every design has."""

    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        return touch_candidates(cell, count, rng, progress=progress)

    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        touch = cell.touch
        n_points = len(touch.names)
        point = np.array([touch.names.index(b) for b in cand.blocks])
        J_p = kinematics.jacobian(robot, data, names, frame=cell.tip, point=touch.probe)  # (M, 3, m)
        J_aux = np.zeros((len(cand.q), 3, 3 + 3 * n_points))
        J_aux[:, :, :3] = kinematics.frame_pose(robot, data, cell.tip)[:, :3, :3]
        for k in range(n_points):
            J_aux[point == k, :, 3 + 3 * k : 6 + 3 * k] = -np.eye(3)
        sigma = cell.touch_sigma_m
        fixed = None
        if touch.known_distances:
            rows = []
            for a in range(n_points):
                for b in range(a + 1, n_points):
                    u = touch.points[a] - touch.points[b]
                    row = np.zeros(3 + 3 * n_points)
                    row[3 + 3 * a : 6 + 3 * a], row[3 + 3 * b : 6 + 3 * b] = u, -u
                    rows.append(row / np.linalg.norm(u) / cell.spacing_sigma_m)
            fixed = np.array(rows)
        labels = [f"probe.{a}" for a in "xyz"] + [f"{name}.{a}" for name in touch.names for a in "xyz"]
        aux_sigma = [PRIOR_SIGMA_AUX["reflector"]] * 3 + [PRIOR_SIGMA_AUX["translation"]] * (3 * n_points)
        return PlanRows(
            params=J_p / sigma,
            aux=J_aux / sigma,
            aux_labels=labels,
            aux_sigma=np.array(aux_sigma),
            sigma_m=sigma,
            frame=cell.tip,
            point=touch.probe.copy(),
            gauge="rigid",
            fixed=fixed,
        )


@dataclass(frozen=True)
class BallbarReadings(Planning):
    """A ballbar between a ball on the flange and fixed pivots (distances): one row per
    reading, the bar's direction u on the ball's motion, ``u^T (T_W_n(q) s - a_k)``, sigma the
    cell's distance sigma; auxiliary: the ball s and the pivots a_k. Readings between two
    configurations are not planned."""

    def candidates(
        self, cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
    ) -> Candidates:
        return ballbar_candidates(cell, count, rng, progress=progress)

    def rows(
        self, robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
    ) -> PlanRows:
        bar = cell.ballbar
        pivot = np.array([bar.names.index(b) for b in cand.blocks])
        T_W_n = kinematics.frame_pose(robot, data, cell.tip)
        u = transform_points(T_W_n, bar.ball) - bar.pivots[pivot]
        u /= np.linalg.norm(u, axis=1)[:, None]
        J_p = u[:, None, :] @ kinematics.jacobian(robot, data, names, frame=cell.tip, point=bar.ball)  # (M, 1, m)
        J_aux = np.zeros((len(cand.q), 1, 3 + 3 * len(bar.names)))
        J_aux[:, 0, :3] = np.einsum("ni,nij->nj", u, T_W_n[:, :3, :3])
        for k in range(len(bar.names)):
            J_aux[pivot == k, 0, 3 + 3 * k : 6 + 3 * k] = -u[pivot == k]
        sigma = cell.distance_sigma_m
        labels = [f"ball.{a}" for a in "xyz"] + [f"{name}.{a}" for name in bar.names for a in "xyz"]
        aux_sigma = [PRIOR_SIGMA_AUX["reflector"]] * 3 + [PRIOR_SIGMA_AUX["translation"]] * (3 * len(bar.names))
        return PlanRows(
            params=J_p / sigma,
            aux=J_aux / sigma,
            aux_labels=labels,
            aux_sigma=np.array(aux_sigma),
            sigma_m=sigma,
            frame=cell.tip,
            point=bar.ball.copy(),
            gauge="rigid",
        )


# -- candidates -------------------------------------------------------------------------------


NOT_IN_VIEW = "viewpoints not reached within the joint limits, or the block not wholly in the nominal camera's view"


def camera_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` reachable configurations, each seeing a block with the nominal camera: random
    viewpoints onto random 2x2 blocks of grid points at the design's standoff and viewing
    angle, reached by IK, kept where the nominal camera sees the block."""
    robot = cell.robot

    # IK on the rigid DH,s model (the gravity deflection does not change what is visible),
    # from two starts per viewpoint: more viewpoints for the same time than six starts.
    ik_cell = replace(cell, robot=robot.with_model("DH,s"))
    views = []
    rounds = requested = 0
    while len(views) < count and rounds < 40:
        rounds += 1
        requests = random_block_requests(cell, max(256, int(1.4 * (count - len(views)))), rng)
        requested += len(requests)
        views += solve_views(
            ik_cell, requests, robot.fk_tool, rng, starts=2, iterations=IK_ITERATIONS, tol=IK_TOL, freeze_converged=True
        )
        if progress:
            progress(f"  candidates: {min(len(views), count)} of {count} reachable, visible configurations")
        if rounds >= 3 and not views:
            raise InputError(cell.source, "objects", "no reachable configuration sees any block of the objects")
    lost = requested - len(views)
    views = views[:count]
    if len(views) < count:
        raise InputError(cell.source, "objects", f"only {len(views)} reachable, visible configurations found")
    return Candidates(
        np.array([v.q for v in views]),
        [v.block[0].name for v in views],
        np.array([[p.position_F for p in v.block] for v in views]),
        discarded={NOT_IN_VIEW: lost} if lost else {},
    )


NOT_SEEN = "no reflector within its acceptance angle of the line to the tracker"
OCCLUDED = "every reflector within its acceptance angle hidden by the robot's own bodies (tracker.link_radii)"
WORKSPACE_SIZE = 2000  # configurations of the region where accuracy counts


def joint_space_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` configurations uniform within the joint limits (fgcal.simulation.design) at
    which the tracker sees at least one reflector on the nominal model: within its acceptance
    angle of the line to the tracker (the cell's ``tracker.normals`` and ``acceptance``); the
    others are drawn and discarded, and counted. ``seen``: which reflectors each candidate's
    tracker sees (only those are measured). The workspace, where accuracy counts, is the
    draws before the filter: the robot works where the tracker does not see it too."""
    robot = cell.robot
    params = robot.parameter_vector()
    tips = sorted(set(cell.reflector_tips))
    batch = max(2000, 4 * count)
    kept_q, kept_seen, workspace = [], [], None
    found = examined = occluded = 0
    while found < count and examined < 400 * count:
        q = uniform_configurations(robot, batch, rng)
        workspace = q[:WORKSPACE_SIZE] if workspace is None else workspace
        data = kinematics.forward(robot, params, q)
        poses = {tip: kinematics.frame_pose(robot, data, tip) for tip in tips}
        seen = cell.reflectors_visible(poses)
        in_view = seen.any(axis=1)
        if cell.link_radii_m is not None:  # the robot's own bodies in the line of sight
            seen &= ~cell.reflectors_occluded(poses, chain_origins(cell, data))
        keep = np.flatnonzero(seen.any(axis=1))[: count - found]
        # Counted up to the last draw kept: the draws after it were not needed.
        drawn = batch if found + len(keep) < count else int(keep[-1]) + 1
        examined += drawn
        occluded += int(np.sum(in_view[:drawn] & ~seen[:drawn].any(axis=1)))
        kept_q.append(q[keep])
        kept_seen.append(seen[keep])
        found += len(keep)
        if progress and found < count:
            progress(f"  candidates: {found} of {count} with a reflector in the tracker's view ({examined} drawn)")
    if found == 0:
        raise InputError(
            cell.source,
            "tracker",
            f"the tracker sees no reflector at any of {examined} configurations within the joint limits "
            "(tracker.pose, tracker.normals, tracker.acceptance)",
        )
    if found < count:
        raise InputError(
            cell.source,
            "tracker",
            f"only {found} of {examined} configurations have a reflector in the tracker's view: ask for fewer "
            "candidates (--candidates), or check tracker.pose, tracker.normals and tracker.acceptance",
        )
    discarded = {NOT_SEEN: examined - found - occluded, OCCLUDED: occluded}
    return Candidates(
        np.concatenate(kept_q),
        None,
        None,
        discarded={reason: n for reason, n in discarded.items() if n},
        seen=np.concatenate(kept_seen),
        seen_label="reflectors",
        workspace=workspace,
    )


def chain_origins(cell: Cell, data: kinematics.KinematicsData) -> np.ndarray:
    """(N, L, 3) the distinct origins of the chain's frames in W, base to flange: the ends of
    its L - 1 segments, which the cell's tracker.link_radii give one radius each."""
    origins = np.transpose(data.frames[:, :, :, 3], (1, 0, 2))  # (N, K + 1, 3), elementary frames
    # A frame at its predecessor's origin (a rotation, a zero offset) is so at every configuration.
    step = np.linalg.norm(np.diff(origins[0], axis=0), axis=1) > 1e-9
    origins = origins[:, np.r_[True, step]]
    if len(cell.link_radii_m) != origins.shape[1] - 1:
        raise InputError(
            cell.source, "tracker.link_radii", f"{origins.shape[1] - 1} radii, one per segment of the robot's chain "
            f"between consecutive distinct frame origins, base to flange; got {len(cell.link_radii_m)}",
        )  # fmt: skip
    return origins


BOARD_UNSEEN = "the board not wholly in the nominal camera's image, or turned beyond its max_view_angle"


def board_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` configurations uniform within the joint limits at which the nominal static
    camera sees the whole board (as the simulator's design draws them); the others are
    discarded and counted. The workspace, where accuracy counts, is the draws before the filter."""
    robot = cell.robot
    setup = cell.static_camera
    params = robot.parameter_vector()
    batch = max(2000, 4 * count)
    kept, workspace, found, examined = [], None, 0, 0
    while found < count and examined < 400 * count:
        q = uniform_configurations(robot, batch, rng)
        workspace = q[:WORKSPACE_SIZE] if workspace is None else workspace
        T_W_n = kinematics.frame_pose(robot, kinematics.forward(robot, params, q), cell.tip)
        keep = np.flatnonzero(board_seen(cell, inverse(setup.pose) @ T_W_n @ setup.board_mount))[: count - found]
        examined += batch if found + len(keep) < count else int(keep[-1]) + 1
        kept.append(q[keep])
        found += len(keep)
        if progress and found < count:
            progress(f"  candidates: {found} of {count} showing the board to the camera ({examined} drawn)")
    if found < count:
        raise InputError(
            cell.source,
            "static_camera",
            f"only {found} of {examined} configurations show the camera the whole board: ask for fewer candidates "
            "(--candidates), or check static_camera.pose and max_view_angle",
        )
    return Candidates(np.concatenate(kept), None, None, discarded={BOARD_UNSEEN: examined - found}, workspace=workspace)


TOUCH_UNREACHED = "the probe not seated in its point within the joint limits, within max_tilt of vertical"


def touch_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` configurations seating the probe in the cell's points on the nominal model:
    a point at random, the probe's axis within ``max_tilt`` of vertical in a random direction
    with a random spin (as the simulator's touches), by inverse kinematics from two random
    starts; the approaches not reached are discarded and counted. Accuracy counts where the
    probe works: over the candidates (the points' neighbourhood, every approach), not the whole
    joint space, which a few points on a table cannot calibrate."""
    robot, touch = cell.robot, cell.touch
    params = robot.parameter_vector()
    q_kept, points, tried, unreached, rounds = [], [], 0, 0, 0
    while len(points) < count and rounds < 40:
        rounds += 1
        batch = max(64, int(1.5 * (count - len(points))))
        which = rng.integers(len(touch.names), size=batch)
        R = np.array([approach_rotation(touch.max_tilt_rad, rng) for _ in range(batch)])
        targets = np.array([pose(R_i, touch.points[k] - R_i @ touch.probe) for k, R_i in zip(which, R, strict=True)])
        q, solved = _reached(robot, params, targets, cell.tip, rng)
        tried += batch
        unreached += int((~solved).sum())
        keep = np.flatnonzero(solved)[: count - len(points)]
        q_kept.append(q[keep])
        points += [touch.names[k] for k in which[keep]]
        if progress and len(points) < count:
            progress(f"  candidates: {len(points)} of {count} touches reached ({tried} tried)")
        if rounds >= 3 and not points:
            raise InputError(cell.source, "touch.points", "the probe reaches none of the points within max_tilt")
    if len(points) < count:
        raise InputError(cell.source, "touch.points", f"only {len(points)} of {tried} approaches reached")
    return Candidates(
        np.concatenate(q_kept),
        points,
        None,
        discarded={TOUCH_UNREACHED: unreached} if unreached else {},
        label_column="point",
        min_per_label=2,
    )


def _reached(robot: Robot, params: np.ndarray, targets: np.ndarray, tip: str, rng: np.random.Generator):
    """Joints (N, n) reaching ``targets`` (N, 4, 4) with ``tip``, by inverse kinematics from two
    random starts within the ranges (revolute joints within +-pi), and which were reached."""
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    solved = np.zeros(len(targets), dtype=bool)
    q = np.zeros((len(targets), robot.n_joints))
    for _ in range(2):
        left = np.flatnonzero(~solved)
        start = rng.uniform(np.maximum(low, -np.pi), np.minimum(high, np.pi), (len(left), robot.n_joints))
        q_try, ok = solve_ik(robot, params, targets[left], start, frame=tip, iterations=IK_ITERATIONS, tol=IK_TOL,
                             freeze_converged=True)  # fmt: skip
        q[left[ok]], solved[left[ok]] = q_try[ok], True
    return q, solved


BALLBAR_UNREACHED = "the ball not reached within the joint limits, the flange within max_tilt of straight down"
MIN_ELEVATION_RAD = np.deg2rad(10.0)  # as the simulator's readings: the bar clear of the pivot's plate


def ballbar_candidates(
    cell: Cell, count: int, rng: np.random.Generator, progress: Callable[[str], None] | None = None
) -> Candidates:
    """``count`` readings to the cell's pivots on the nominal model: a pivot at random, the ball
    at a random length within the bar's travel in a random direction above the pivot's plane,
    the flange pointing down within ``max_tilt`` with a random spin (as the simulator's), by
    inverse kinematics from two random starts; the readings not reached are discarded and
    counted. Accuracy counts over the candidates (where the ball works)."""
    robot, bar = cell.robot, cell.ballbar
    if not bar.names:
        raise InputError(cell.source, "ballbar.pivots", "readings between configurations are not planned yet")
    params = robot.parameter_vector()
    q_kept, pivots, unreached, rounds = [], [], 0, 0
    while len(pivots) < count and rounds < 40:
        rounds += 1
        batch = max(64, int(1.5 * (count - len(pivots))))
        which = rng.integers(len(bar.names), size=batch)
        length = rng.uniform(*bar.length_m, batch)
        azimuth = rng.uniform(-np.pi, np.pi, batch)
        elevation = np.arcsin(rng.uniform(np.sin(MIN_ELEVATION_RAD), 1.0, batch))
        direction = np.stack(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
        )
        centres = bar.pivots[which] + length[:, None] * direction
        R = np.array([approach_rotation(bar.max_tilt_rad, rng) for _ in range(batch)])
        targets = np.array([pose(R_i, c - R_i @ bar.ball) for c, R_i in zip(centres, R, strict=True)])
        q, solved = _reached(robot, params, targets, cell.tip, rng)
        unreached += int((~solved).sum())
        keep = np.flatnonzero(solved)[: count - len(pivots)]
        q_kept.append(q[keep])
        pivots += [bar.names[k] for k in which[keep]]
        if progress and len(pivots) < count:
            progress(f"  candidates: {len(pivots)} of {count} readings reached")
        if rounds >= 3 and not pivots:
            raise InputError(cell.source, "ballbar.pivots", "the ball reaches no pivot's travel within max_tilt")
    if len(pivots) < count:
        raise InputError(cell.source, "ballbar.pivots", f"only {len(pivots)} readings reached")
    return Candidates(
        np.concatenate(q_kept),
        pivots,
        None,
        discarded={BALLBAR_UNREACHED: unreached} if unreached else {},
        label_column="pivot",
        min_per_label=6,  # three for the pivot, three for the ball, more for the robot
    )


# -- rows ---------------------------------------------------------------------------------------


def _camera_rows(
    robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str], rotation: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows on the parameters and on the fixture, and the block points in the camera frame."""
    T_C_W = inverse(kinematics.frame_pose(robot, data, "tool"))
    J_body = kinematics.jacobian(robot, data, names, frame="tool")  # (M, 6, m)
    p_W = transform_points(cell.fixture_pose[None, None], cand.points_F)  # (M, 4, 3)
    p_C = transform_points(T_C_W[:, None], p_W)
    # The camera moves by its body twist (w, v): d p_C = p_C x w - v = [skew(p_C), -I] (w, v).
    lever = np.concatenate([skew(p_C), np.broadcast_to(-np.eye(3), (*p_C.shape, 3))], axis=-1)  # (M, 4, 3, 6)
    J_p = (lever @ J_body[:, None]).reshape(len(cand.q), -1, len(names))
    R_C_W = T_C_W[:, None, :3, :3]
    # The fixture moves in W by (w, t): d p_W = w x p_W + t.
    blocks = [np.broadcast_to(R_C_W, (*p_C.shape, 3))]
    if rotation:
        blocks.insert(0, -R_C_W @ skew(p_W))
    J_aux = np.concatenate(blocks, axis=-1).reshape(len(cand.q), -1, 3 * len(blocks))
    return J_p, J_aux, p_C


def _grouped(J_p: np.ndarray, J_aux: np.ndarray, p_C: np.ndarray, group: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of images whose groups of ``group`` (drawn at random) each lose a common position:
    in expectation an image loses 1/group of its own points' common position (the part of its
    information a translation of its block would explain). With P the projector onto that
    translation (the block's points moving together in the camera frame), the rows become
    ``(I - a P) J``, ``(2a - a^2) = 1/group``: their information is ``J^T J - J^T P J / group``.
    The design's common translation (the auxiliary unknown) stays."""
    n_points = p_C.shape[1]
    a = 1.0 - np.sqrt(1.0 - 1.0 / group)
    # The block's points' translation in the camera frame: rows of every point, one 3x3 each.
    T = np.tile(np.eye(3), (n_points, 1)) / np.sqrt(n_points)  # (3r, 3) orthonormal columns

    def project(J: np.ndarray) -> np.ndarray:
        return J - a * T @ (T.T @ J)

    return project(J_p), project(J_aux)


def _board_rows(
    robot: Robot, data: kinematics.KinematicsData, cell: Cell, names: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """Six rows per candidate carrying exactly the information of all the board's corners'
    pixels (pinhole; the distortion left out of the derivatives): every pixel moves with the
    board's twist (w, v) in the camera frame, ``d p_C = w x p_C + v``, so the rows D of all
    corners on that twist (2k x 6) compress to ``chol(D^T D)^T`` (6 x 6) times the twist's
    Jacobian G on the parameters (the tip's body twist carried to the camera), the camera's pose
    (moved in its frame) and the board's mounting (moved in the tip's frame)."""
    setup = cell.static_camera
    T_W_n = kinematics.frame_pose(robot, data, cell.tip)
    T_C_n = inverse(setup.pose)[None] @ T_W_n  # (M, 4, 4)
    p_C = transform_points((T_C_n @ setup.board_mount)[:, None], setup.board_points)  # (M, k, 3)
    x, y, z = p_C[..., 0], p_C[..., 1], p_C[..., 2]
    cam = setup.camera
    P = np.zeros((*p_C.shape[:2], 2, 3))
    P[..., 0, 0], P[..., 0, 2] = cam.fx / z, -cam.fx * x / z**2
    P[..., 1, 1], P[..., 1, 2] = cam.fy / z, -cam.fy * y / z**2
    eye = np.broadcast_to(np.eye(3), (*p_C.shape, 3))
    D = (P @ np.concatenate([-skew(p_C), eye], axis=-1)).reshape(len(p_C), -1, 6)  # (M, 2k, 6)
    L = np.linalg.cholesky(np.swapaxes(D, 1, 2) @ D)  # (M, 6, 6)
    # A twist (w, v) of the tip in its own frame moves the board by (R w, R v + t x R w) in C.
    R, t = T_C_n[:, :3, :3], T_C_n[:, :3, 3]
    A = np.zeros((len(p_C), 6, 6))
    A[:, :3, :3], A[:, 3:, 3:], A[:, 3:, :3] = R, R, skew(t) @ R
    G_p = A @ kinematics.jacobian(robot, data, names, frame=cell.tip)  # (M, 6, m)
    G_aux = np.concatenate([np.broadcast_to(np.eye(6), A.shape), A], axis=2)  # camera, board
    Lt = np.swapaxes(L, 1, 2)
    return Lt @ G_p, Lt @ G_aux


def _tracker_rows(
    robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    R_T_W = cell.tracker_pose[:3, :3].T
    n_conf, n_targets = len(cand.q), len(cell.tracker_targets)
    tips = cell.tracker_target_tips or ("flange",) * n_targets  # a tree's reflectors: on their tips
    J_p = np.zeros((n_conf, 3 * n_targets, len(names)))
    J_aux = np.zeros((n_conf, 3 * n_targets, 6 + 3 * n_targets))
    for t, s in enumerate(cell.tracker_targets):
        rows = slice(3 * t, 3 * t + 3)
        T_W_n = kinematics.frame_pose(robot, data, tips[t])
        J_p[:, rows] = R_T_W @ kinematics.jacobian(robot, data, names, frame=tips[t], point=s)
        p_W = transform_points(T_W_n, s)
        # The tracker moves in W by (w, t): d p_T = R_T_W (p_W x w - t); the reflector by d s.
        J_aux[:, rows, :3] = R_T_W @ skew(p_W)
        J_aux[:, rows, 3:6] = -R_T_W
        J_aux[:, rows, 6 + 3 * t : 9 + 3 * t] = R_T_W @ T_W_n[:, :3, :3]
    return J_p, J_aux
