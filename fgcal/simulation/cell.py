"""Calibration cell description (YAML): robot, calibration objects, camera, tracker,
noise, perturbation ranges of the simulated true robot, and the design of configurations.
The schema is documented in docs/formats.md."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import Fields, read_yaml, to_float
from ..core.schema import validate
from ..core.se3 import pose_from_xyz_rpy, transform_points
from ..core.units import parse_units
from ..data.dataset import plane_normal, robot_tip
from ..model.camera import Camera, parse_camera
from ..model.motion import MotionHistory
from ..model.parameters import default_compliant_joints
from ..model.robot import Robot
from ..model.robot_io import load_referenced, robot_reference
from . import MAX_CONFIGURATIONS
from .schema import CellFile

SIDES = ("+x", "-x", "+y", "-y", "+z", "-z")
DESIGNS = ("seed", "space_filling")
# A spherically mounted retroreflector returns the beam within about +-30 deg of its axis.
REFLECTOR_ACCEPTANCE_DEG = 30.0
APPROACHES = ("previous", "from_below")


@dataclass(frozen=True)
class GridPoint:
    """A point on a calibration object's side; ``position_F`` in the fixture frame (m)."""

    name: str
    obj: str
    side: str
    row: int
    col: int
    position_F: np.ndarray


@dataclass(frozen=True)
class Side:
    """One grid-carrying side of a cuboid: points[row][col], outward normal in F."""

    obj: str
    side: str
    normal_F: np.ndarray
    points: list[list[GridPoint]]

    def block(self, row: int, col: int) -> list[GridPoint]:
        """The 2x2 block of grid points whose first corner is (row, col)."""
        return [
            self.points[row][col],
            self.points[row][col + 1],
            self.points[row + 1][col + 1],
            self.points[row + 1][col],
        ]

    @property
    def n_block_rows(self) -> int:
        return len(self.points) - 1

    @property
    def n_block_cols(self) -> int:
        return len(self.points[0]) - 1


@dataclass(frozen=True)
class Perturbation:
    """Half-widths of the uniform deviations of the simulated true robot (SI)."""

    length_m: float
    angle_rad: float
    distortion_rad: float
    compliance_range: tuple[float, float]
    compliant_joints: tuple[int, ...]
    base_length_m: float
    base_angle_rad: float  # about the vertical (yaw)
    base_tilt_rad: float  # about the horizontal axes: unmeasured tilt against gravity
    tool_length_m: float
    tool_angle_rad: float
    mass_scale: float = 0.0  # half-width of the true mass scales' deviation from 1 (robot mass_groups)


@dataclass(frozen=True)
class MotionTruth:
    """The true robot's motion-history terms (fgcal.model.motion), rad per joint, and how the design
    reaches each configuration: from the one before (``previous``) or from ``offset_rad`` below
    on every joint (``from_below``: a unidirectional approach)."""

    lost_motion_rad: np.ndarray
    speed_rad: np.ndarray
    approach: str
    offset_rad: float

    def parameters(self) -> dict[str, float]:
        """The lm and lv values by parameter name."""
        named = {f"lm{i}": float(v) for i, v in enumerate(self.lost_motion_rad, start=1)}
        return named | {f"lv{i}": float(v) for i, v in enumerate(self.speed_rad, start=1)}

    def history(self, q: np.ndarray) -> MotionHistory:
        """How the design's configurations (in measurement order) are reached."""
        if self.approach == "from_below":
            return MotionHistory(q - self.offset_rad, np.ones(len(q)))
        return MotionHistory.in_order(q)


@dataclass(frozen=True)
class Design:
    kind: str
    n_configurations: int
    blocks_per_side: int
    views_per_block: int
    standoff_m: tuple[float, float]
    max_view_angle_rad: float


@dataclass(frozen=True)
class TouchSetup:
    """A probe on the flange touching fixed points (sockets) in the cell, all in SI."""

    probe: np.ndarray  # (3,) the probe's centre in the flange frame (the true one)
    names: tuple[str, ...]
    points: np.ndarray  # (k, 3) in W
    touches_per_point: int
    max_tilt_rad: float  # of the probe's approach from straight down
    known_distances: bool  # the drawing gives the distances between the points


@dataclass(frozen=True)
class BallbarSetup:
    """A ballbar (or 1D gauge) between a ball on the flange and fixed pivots, all in SI."""

    ball: np.ndarray  # (3,) the ball's centre in the flange frame (the true one)
    names: tuple[str, ...]
    pivots: np.ndarray  # (k, 3) in W
    length_m: tuple[float, float]  # the bar's travel: shortest and longest reading
    readings_per_pivot: int
    max_tilt_rad: float  # of the flange's z axis from straight down
    # Readings between the ball at two configurations (a two-ball bar, an interferometer's
    # travel): how many, and the sphere (centre in W, radius) where their first ends lie.
    pairs: int = 0
    pairs_centre: np.ndarray | None = None
    pairs_radius_m: float = 0.0


@dataclass(frozen=True)
class StaticCameraSetup:
    """A camera fixed in the cell watching a board on the flange (eye-to-hand), all in SI."""

    camera: Camera
    pose: np.ndarray  # T_W_C
    board_mount: np.ndarray  # T_n_B: the board's frame on the flange
    board_points: np.ndarray  # (m, 3) the board's corners in its frame (z = 0)
    point_names: tuple[str, ...]
    max_view_angle_rad: float  # between the board's normal and the line of sight


@dataclass(frozen=True)
class ContactCellSetup:
    """Balls on the tips of a tree touching each other and planes of the cell (SI): the drawing's
    (nominal) values, how far the truth is off them, and how many contacts are made."""

    names: tuple[str, ...]
    tips: tuple[str, ...]
    centres: np.ndarray  # (k, 3) on their tips, nominal
    radii: np.ndarray  # (k,)
    plane_names: tuple[str, ...]
    normals: np.ndarray  # (p, 3) unit, nominal, in W
    offsets: np.ndarray  # (p,)
    self_contacts: int
    plane_contacts: int  # per ball and plane
    centre_error_m: float
    plane_angle_error_rad: float
    plane_offset_error_m: float
    position_sigma_m: float
    gauge_length_m: float = 0.0  # a ballbar between the first two balls (0: none)
    gauge_travel_m: float = 0.0
    gauge_readings: int = 0
    held: tuple[int, ...] = ()  # 0-based q columns held still
    held_at: tuple[float, ...] = ()  # rad or m


@dataclass(frozen=True)
class SelfObservationSetup:
    """Cameras on links seeing checkerboards on tips (SI; the drawing's poses)."""

    camera_names: tuple[str, ...]
    joints: tuple[int, ...]  # 1-based link numbers (0: the base)
    mountings: np.ndarray  # (c, 4, 4) T_link_C
    cameras: tuple[Camera, ...]
    board_names: tuple[str, ...]
    tips: tuple[str, ...]
    poses: np.ndarray  # (b, 4, 4) T_tip_B
    corners: tuple[tuple[int, int], ...]
    squares: tuple[float, ...]
    views: int
    length_error_m: float
    angle_error_rad: float
    max_view_angle_rad: float


# What can measure in a cell, the more specific first: a 6D probe is a tracker's too, and a
# camera cell has a tracker besides; a robot touching itself carries a tracker for validation.
INSTRUMENTS = ("static_camera", "touch", "ballbar", "self_contact", "planes", "tip_gauge", "self_observation",
               "tracker_probe", "camera", "tracker")  # fmt: skip


@dataclass(frozen=True)
class Cell:
    name: str
    source: str
    robot_reference: str | dict  # bundled robot name, the robot file's absolute path, or {file, tip}
    robot: Robot  # carrying the nominal camera mounting and payload
    fixture_pose: np.ndarray  # T_W_F
    sides: list[Side]
    camera: Camera | None  # None: a tracker cell (no camera, no objects)
    tracker_pose: np.ndarray  # T_W_T
    tracker_targets: np.ndarray  # (m, 3) in the flange frame (or their tips' frames), m
    camera_point_sigma_m: float
    pixel_sigma_px: float
    tracker_sigma_m: float
    perturbation: Perturbation
    design: Design
    touch: TouchSetup | None = None  # a touch cell: a probe touching fixed points
    touch_sigma_m: float = 0.0
    spacing_sigma_m: float = 0.0
    tracker_probe: np.ndarray | None = None  # T_n_E of a 6D probe: the tracker measures its pose too
    tracker_angle_sigma_rad: float = 0.0
    ballbar: BallbarSetup | None = None
    distance_sigma_m: float = 0.0
    static_camera: StaticCameraSetup | None = None
    has_tracker: bool = True  # a laser tracker measures the reflectors (tracker_targets)
    tracker_target_tips: tuple[str, ...] = ()  # per target, the tree's tip it is on (empty: all on the flange)
    # Per target: the reflector's axis (unit, in its tip's frame; default z) and its acceptance
    # half-angle (rad; default REFLECTOR_ACCEPTANCE_DEG): the tracker sees it within that cone.
    tracker_normals: np.ndarray | None = None  # (m, 3); None: every reflector along its tip's z axis
    tracker_acceptance_rad: np.ndarray | None = None  # (m,); None: the default acceptance
    # The robot's bodies between tracker and reflectors: a capsule per segment between
    # consecutive frames' origins, this radius each (m); None: not given (not checked).
    link_radii_m: np.ndarray | None = None
    tip: str = "flange"  # the tree's tip carrying the probe, ball, board or reflectors (cell tip:)
    motion: MotionTruth | None = None  # the true robot's lost motion (its model is then DH,s,e,h)
    contact: ContactCellSetup | None = None  # balls on the tips touching each other and planes
    contact_sigma_m: float = 0.0
    validation: tuple[str, ...] = ()  # instruments (INSTRUMENTS) measured for validation only
    self_observation: SelfObservationSetup | None = None  # cameras on a link seeing boards on the tips

    @property
    def instruments(self) -> list[str]:
        """What measures in this cell (INSTRUMENTS), the one the cell is built for first."""
        present = {
            "static_camera": self.static_camera is not None,
            "touch": self.touch is not None,
            "ballbar": self.ballbar is not None,
            "self_contact": self.contact is not None and self.contact.self_contacts > 0,
            "planes": self.contact is not None and self.contact.plane_contacts > 0 and bool(self.contact.plane_names),
            "tip_gauge": self.contact is not None and self.contact.gauge_readings > 0,
            "self_observation": self.self_observation is not None,
            "tracker_probe": self.tracker_probe is not None,
            "camera": self.camera is not None,
            "tracker": self.has_tracker,
        }
        return [name for name in INSTRUMENTS if present[name]]

    def points(self) -> list[GridPoint]:
        return [p for side in self.sides for row in side.points for p in row]

    @property
    def reflector_normals(self) -> np.ndarray:
        """(m, 3) each reflector's axis in its tip's frame (unit)."""
        if self.tracker_normals is not None:
            return self.tracker_normals
        return np.tile([0.0, 0.0, 1.0], (len(self.tracker_targets), 1))

    @property
    def reflector_acceptance_rad(self) -> np.ndarray:
        """(m,) each reflector's acceptance half-angle (rad)."""
        if self.tracker_acceptance_rad is not None:
            return self.tracker_acceptance_rad
        return np.full(len(self.tracker_targets), np.radians(REFLECTOR_ACCEPTANCE_DEG))

    @property
    def reflector_tips(self) -> tuple[str, ...]:
        """Each reflector's tip (the flange unless a tree's targets name theirs)."""
        return self.tracker_target_tips or (self.robot.flange_name,) * len(self.tracker_targets)

    def reflector_angles(self, T_W_tips: dict[str, np.ndarray]) -> np.ndarray:
        """(N, m) the angle (rad) between each reflector's axis and its line to the tracker, at
        N configurations whose tip poses ``T_W_tips`` ({tip: (N, 4, 4)}) are given."""
        tips = self.reflector_tips
        angles = []
        for s, normal, tip in zip(self.tracker_targets, self.reflector_normals, tips, strict=True):
            T = T_W_tips[tip]
            line = self.tracker_pose[:3, 3] - transform_points(T, s)
            axis = T[:, :3, :3] @ normal
            cosine = np.sum(line * axis, axis=1) / np.maximum(np.linalg.norm(line, axis=1), 1e-12)
            angles.append(np.arccos(np.clip(cosine, -1.0, 1.0)))
        return np.array(angles).T.reshape(-1, len(self.tracker_targets))

    def reflectors_visible(self, T_W_tips: dict[str, np.ndarray]) -> np.ndarray:
        """(N, m) whether the tracker sees each reflector: within its acceptance angle."""
        return self.reflector_angles(T_W_tips) <= self.reflector_acceptance_rad

    def reflectors_occluded(self, T_W_tips: dict[str, np.ndarray], origins: np.ndarray) -> np.ndarray:
        """(N, m) whether the robot's own bodies hide each reflector from the tracker: its line to
        the tracker passes within a body's radius of the body's axis (``origins``: (N, K, 3)
        the frames' origins in W, base to flange; body k from origin k to k+1, radius
        ``link_radii_m[k]``). A body whose capsule holds the reflector itself (the link it is
        mounted on) is not judged. False everywhere where the cell gives no radii."""
        tips = self.tracker_target_tips or ("flange",) * len(self.tracker_targets)
        n = len(origins)
        out = np.zeros((n, len(self.tracker_targets)), dtype=bool)
        if self.link_radii_m is None:
            return out
        radii = self.link_radii_m
        starts, ends = origins[:, :-1][:, : len(radii)], origins[:, 1:][:, : len(radii)]
        tracker = np.broadcast_to(self.tracker_pose[:3, 3], (n, 3))
        for t, (s, tip) in enumerate(zip(self.tracker_targets, tips, strict=True)):
            reflector = transform_points(T_W_tips[tip], s)  # (N, 3)
            for k in range(starts.shape[1]):
                inside = point_segment_distance(reflector, starts[:, k], ends[:, k]) <= radii[k]
                near = segment_distance(reflector, tracker, starts[:, k], ends[:, k]) < radii[k]
                out[:, t] |= near & ~inside
        return out


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) the distance from points p to segments a-b (each (N, 3))."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=1) / np.maximum(np.sum(ab * ab, axis=1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """(N,) the shortest distance between segments p0-p1 and q0-q1 (each (N, 3)): the closest
    points' parameters clamped to the segments (Ericson, Real-Time Collision Detection 5.1.9);
    p0-p1 must have a length, q0-q1 may be a point."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e = np.sum(d1 * d1, axis=1), np.sum(d2 * d2, axis=1)
    b, c, f = np.sum(d1 * d2, axis=1), np.sum(d1 * r, axis=1), np.sum(d2 * r, axis=1)
    point = e <= 1e-24  # q0-q1 is a point
    denominator = a * e - b * b
    parallel = denominator <= 1e-12 * a * np.maximum(e, 1e-300)
    s = np.where(parallel, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denominator), 0.0, 1.0))
    t = np.where(point, 0.0, (b * s + f) / np.where(point, 1.0, e))
    below, above = t < 0.0, t > 1.0
    s = np.where(below | point, np.clip(-c / a, 0.0, 1.0), s)
    s = np.where(above & ~point, np.clip((b - c) / a, 0.0, 1.0), s)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm((p0 + s[:, None] * d1) - (q0 + t[:, None] * d2), axis=1)


def _pose(fields: Fields, key: str, to_m: float, to_rad: float) -> np.ndarray:
    sub = fields.sub(key, {})
    return pose_from_xyz_rpy(sub.vector("xyz", 3, [0, 0, 0], to_m), sub.vector("rpy", 3, [0, 0, 0], to_rad))


def _cuboid_sides(obj: Fields, pitch: float, margin: float, to_m: float, to_rad: float) -> list[Side]:
    name = obj.string("name")
    size = obj.vector("size", 3, scale=to_m)
    if np.any(size <= 0):
        raise obj.error("size", "cuboid edge lengths must be > 0")
    T_F_O = _pose(obj, "pose", to_m, to_rad)
    sides = []
    for j, label in enumerate(obj.items("sides")):
        if label not in SIDES:
            raise InputError(obj.source, f"{obj.path('sides')}[{j}]", f"unknown side {label!r} (one of {SIDES})")
        axis = "xyz".index(label[1])
        sign = 1.0 if label[0] == "+" else -1.0
        u_axis, v_axis = [a for a in range(3) if a != axis]
        counts = [int(np.floor((size[a] - 2 * margin) / pitch + 1e-9)) + 1 for a in (u_axis, v_axis)]
        if min(counts) < 2:
            raise obj.error(
                "size", f"side {label} is too small for a 2x2 block at pitch {pitch} m and margin {margin} m"
            )
        rows = []
        for r in range(counts[1]):
            row = []
            for c in range(counts[0]):
                local = np.zeros(3)
                local[axis] = sign * size[axis] / 2
                local[u_axis] = (
                    -size[u_axis] / 2 + margin + c * pitch + (size[u_axis] - 2 * margin - (counts[0] - 1) * pitch) / 2
                )
                local[v_axis] = (
                    -size[v_axis] / 2 + margin + r * pitch + (size[v_axis] - 2 * margin - (counts[1] - 1) * pitch) / 2
                )
                row.append(
                    GridPoint(f"{name}{label}_r{r:02d}c{c:02d}", name, label, r, c, transform_points(T_F_O, local))
                )
            rows.append(row)
        normal = np.zeros(3)
        normal[axis] = sign
        sides.append(Side(name, label, T_F_O[:3, :3] @ normal, rows))
    return sides


def _named_points(section: Fields, key: str, to_m: float, minimum: int, needed: str) -> tuple[list[str], list]:
    """The ``{name, xyz}`` list under ``key``: names and positions (m), at least ``minimum``,
    names unique."""
    names, points = [], []
    for point in section.sub_list(key):
        names.append(point.string("name"))
        points.append(point.vector("xyz", 3, scale=to_m))
    if len(points) < minimum:
        raise section.error(key, f"at least {minimum} {needed}, got {len(points)}")
    if len(set(names)) != len(names):
        raise section.error(key, f"duplicate {key[:-1]} names")
    return names, points


def _touch(touch: Fields, to_m: float, to_rad: float) -> TouchSetup:
    names, points = _named_points(touch, "points", to_m, 3, "points are needed to touch")
    known = touch.raw("known_distances", True)
    if not isinstance(known, bool):
        raise touch.error("known_distances", f"expected true or false, got {known!r}")
    tilt = touch.number("max_tilt", 40.0 * np.pi / 180 / to_rad, to_rad, positive=True)
    if tilt >= np.pi / 2:
        raise touch.error("max_tilt", "the probe approaches from above: below 90 deg")
    return TouchSetup(
        probe=touch.vector("probe", 3, scale=to_m),
        names=tuple(names),
        points=np.array(points),
        touches_per_point=touch.integer("touches_per_point", 12, minimum=3, maximum=1000),
        max_tilt_rad=float(tilt),
        known_distances=known,
    )


def _ballbar(bar: Fields, to_m: float, to_rad: float) -> BallbarSetup:
    pairs, centre, radius = 0, None, 0.0
    if bar.has("between_configurations"):
        between = bar.sub("between_configurations")
        pairs = between.integer("readings", minimum=6, maximum=MAX_CONFIGURATIONS // 2)
        centre = between.vector("centre", 3, scale=to_m)
        radius = between.number("radius", scale=to_m, nonnegative=True)
    names, pivots = [], []
    if bar.has("pivots") or not pairs:  # readings between configurations need no pivot
        names, pivots = _named_points(bar, "pivots", to_m, 1, "pivot is needed")
    length = bar.vector("length", 2, scale=to_m)
    if not 0 < length[0] <= length[1]:
        raise bar.error("length", "expected [shortest, longest] with 0 < shortest <= longest")
    tilt = bar.number("max_tilt", 45.0 * np.pi / 180 / to_rad, to_rad, positive=True)
    if tilt >= np.pi / 2:
        raise bar.error("max_tilt", "the tool points down: below 90 deg")
    return BallbarSetup(
        ball=bar.vector("ball", 3, scale=to_m),
        names=tuple(names),
        pivots=np.array(pivots).reshape(-1, 3),
        length_m=(float(length[0]), float(length[1])),
        readings_per_pivot=bar.integer("readings_per_pivot", 40, minimum=6, maximum=1000),
        max_tilt_rad=float(tilt),
        pairs=pairs,
        pairs_centre=centre,
        pairs_radius_m=float(radius),
    )


def _contact(section: Fields, robot: Robot, to_m: float, to_rad: float) -> ContactCellSetup:
    names, tips, centres, radii = [], [], [], []
    for ball in section.sub_list("elements"):
        tip = robot_tip(ball, "tip", robot)
        names.append(ball.string("name"))
        tips.append(tip)
        centres.append(ball.vector("xyz", 3, scale=to_m))
        radii.append(ball.number("radius", scale=to_m, positive=True))
    plane_names, normals, offsets = [], [], []
    for plane in section.sub_list("planes") if section.has("planes") else []:
        normal = plane_normal(plane)
        plane_names.append(plane.string("name"))
        normals.append(normal)
        offsets.append(plane.number("offset", scale=to_m))
    for what, labels in (("elements", names), ("planes", plane_names)):
        if len(set(labels)) != len(labels):
            raise section.error(what, f"duplicate name among {labels}")
    if not names:
        raise section.error("elements", "at least one ball")
    self_contacts = section.integer("self_contacts", 40, minimum=0)
    if self_contacts and (len(names) < 2 or tips[0] == tips[1]):
        raise section.error("self_contacts", "join the first two balls, which must be on two different tips")
    gauge = section.sub("gauge") if section.has("gauge") else None
    if gauge is not None and (len(names) < 2 or tips[0] == tips[1]):
        raise section.error("gauge", "joins the first two balls, which must be on two different tips")
    gauge_values = (
        (gauge.number("length", scale=to_m, positive=True), gauge.number("travel", scale=to_m, positive=True),
         gauge.integer("readings", 100, minimum=1)) if gauge is not None else (0.0, 0.0, 0)
    )  # fmt: skip
    held, held_at = (), ()
    if section.has("hold"):
        hold = section.sub("hold")
        held = tuple(int(j) for j in hold.items("joints"))
        for j in held:
            if not 1 <= j <= robot.n_joints:
                raise hold.error("joints", f"joint {j} does not exist: {robot.name} has q1 to q{robot.n_joints}")
        held_at = tuple(hold.vector("at", len(held), scale=to_rad))
        held = tuple(j - 1 for j in held)
    return ContactCellSetup(
        tuple(names), tuple(tips), np.array(centres), np.array(radii), tuple(plane_names),
        np.array(normals).reshape(-1, 3), np.array(offsets), self_contacts,
        section.integer("plane_contacts", 12, minimum=0),
        section.number("centre_error", 1e-3 / to_m, to_m, nonnegative=True),
        section.number("plane_angle_error", np.radians(1.0) / to_rad, to_rad, nonnegative=True),
        section.number("plane_offset_error", 5e-3 / to_m, to_m, nonnegative=True),
        section.number("position_sigma", 2e-3 / to_m, to_m, positive=True),
        *gauge_values,
        held,
        held_at,
    )  # fmt: skip


def _self_observation(section: Fields, robot: Robot, to_m: float, to_rad: float) -> SelfObservationSetup:
    cameras = section.sub_list("cameras")
    boards = section.sub_list("boards")
    for camera in cameras:
        if camera.integer("joint", minimum=0) > robot.n_links:
            raise camera.error("joint", f"{robot.name} has joints 1 to {robot.n_links} (0: the base)")
    tips = []
    for board in boards:
        tips.append(robot_tip(board, "tip", robot))
        corners = board.vector("corners", 2)
        if np.any(corners < 2) or np.any(corners != np.round(corners)):
            raise board.error("corners", f"expected two integers >= 2 (columns, rows), got {corners.tolist()}")
    names = [c.string("name") for c in cameras] + [b.string("name") for b in boards]
    if len(set(names)) != len(names) or set(names) & set(robot.tip_names):
        raise section.error("cameras", f"names must differ from each other and from the robot's tips: {names}")
    error = section.vector("mounting_error", 2, [2e-3 / to_m, np.radians(1.0) / to_rad])
    angle = section.number("max_view_angle", np.radians(60.0) / to_rad, to_rad, positive=True)
    if angle >= np.pi / 2:
        raise section.error("max_view_angle", "a camera sees a board's face: below 90 deg")
    return SelfObservationSetup(
        tuple(c.string("name") for c in cameras), tuple(c.integer("joint") for c in cameras),
        np.array([_pose(c, "mounting", to_m, to_rad) for c in cameras]).reshape(-1, 4, 4),
        tuple(parse_camera(c) for c in cameras), tuple(b.string("name") for b in boards), tuple(tips),
        np.array([_pose(b, "pose", to_m, to_rad) for b in boards]).reshape(-1, 4, 4),
        tuple((int(b.vector("corners", 2)[0]), int(b.vector("corners", 2)[1])) for b in boards),
        tuple(b.number("square", scale=to_m, positive=True) for b in boards), section.integer("views", 200, minimum=1),
        float(error[0] * to_m), float(error[1] * to_rad), float(angle),
    )  # fmt: skip


def _static_camera(section: Fields, to_m: float, to_rad: float) -> StaticCameraSetup:
    board = section.sub("board")
    corners = board.vector("corners", 2)
    if np.any(corners < 2) or np.any(corners != np.round(corners)):
        raise board.error("corners", f"expected two integers >= 2 (columns, rows), got {corners.tolist()}")
    square = board.number("square", scale=to_m, positive=True)
    cols, rows = int(corners[0]), int(corners[1])
    points = np.array([[c * square, r * square, 0.0] for r in range(rows) for c in range(cols)])
    points[:, :2] -= points[:, :2].mean(axis=0)  # the board's frame at its centre
    angle = section.number("max_view_angle", 60.0 * np.pi / 180 / to_rad, to_rad, positive=True)
    if angle >= np.pi / 2:
        raise section.error("max_view_angle", "the camera sees the board's face: below 90 deg")
    return StaticCameraSetup(
        camera=parse_camera(section),
        pose=_pose(section, "pose", to_m, to_rad),
        board_mount=_pose(board, "mount", to_m, to_rad),
        board_points=points,
        point_names=tuple(f"b_r{r:02d}c{c:02d}" for r in range(rows) for c in range(cols)),
        max_view_angle_rad=float(angle),
    )


def _motion_truth(doc: Fields, n_joints: int, to_rad: float) -> MotionTruth | None:
    """The ``motion_history`` section: lost_motion and speed, one value per joint (the cell's
    angle unit), approach (previous or from_below) and approach_offset (angle unit)."""
    if not doc.has("motion_history"):
        return None
    section = doc.sub("motion_history")
    zeros = [0.0] * n_joints
    lost = np.array(section.vector("lost_motion", n_joints, zeros, to_rad))
    speed = np.array(section.vector("speed", n_joints, zeros, to_rad))
    for key, values in (("lost_motion", lost), ("speed", speed)):
        if np.any(np.abs(values) > np.radians(0.5)):
            raise section.error(key, "implausible: beyond 0.5 degrees (hundredths of a degree are usual)")
    offset = section.number("approach_offset", np.radians(2.0) / to_rad, to_rad, positive=True)
    if offset > np.radians(30.0):
        raise section.error("approach_offset", "at most 30 degrees")
    return MotionTruth(lost, speed, section.string("approach", "previous", APPROACHES), offset)


def load_cell(path: str | Path) -> Cell:
    """Load and validate a cell file; every error names the file and field."""
    path = Path(path)
    raw = read_yaml(path)
    validate(raw, CellFile, path)  # keys, types, nulls and choices; the checks below need the robot
    doc = Fields(raw, path)
    units = parse_units(doc.raw("units", None), path)
    to_m, to_rad = units.to_m, units.to_rad
    robot_ref = robot_reference(path.parent, doc.raw("robot"), path)
    try:
        robot = load_referenced(robot_ref)
    except InputError as exc:
        raise InputError(path, "robot", str(exc)) from None

    # A tracker cell has no camera and no objects: its configurations are drawn in joint space.
    camera_fields = doc.sub("camera") if doc.has("camera") or doc.has("objects") else None
    camera = None
    if camera_fields is not None:
        camera = parse_camera(camera_fields)
    payload = doc.sub("payload", {})
    robot = robot.with_tool(
        _pose(camera_fields, "mounting", to_m, to_rad) if camera_fields is not None else robot.tool_pose,
        payload_mass=payload.number("mass", robot.payload_mass, nonnegative=True),
        payload_com=payload.vector("com", 3, robot.payload_com.tolist(), to_m),
    )
    if doc.has("base"):
        robot = replace(robot, base_pose=_pose(doc, "base", to_m, to_rad))
    tip = robot_tip(doc, "tip", robot, default=robot.flange_name)
    if tip != robot.flange_name and camera_fields is not None:
        raise doc.error("tip", "a flange camera is the flange's tool: a tree's other tips carry targets, not cameras")

    grid = doc.sub("grid", {})
    pitch = grid.number("pitch", 40.0 * 1e-3 / to_m, to_m, positive=True)
    margin = grid.number("margin", pitch / to_m, to_m, nonnegative=True)
    sides = []
    for obj in doc.sub_list("objects") if camera is not None else []:
        sides += _cuboid_sides(obj, pitch, margin, to_m, to_rad)
    if camera is not None and not sides:
        raise doc.error("objects", "at least one object side with a grid is needed")
    names = [s.obj for s in sides]
    if len({(s.obj, s.side) for s in sides}) != len(sides):
        raise doc.error("objects", f"duplicate object name or side among {sorted(set(names))}")

    tracker = doc.sub("tracker", {})
    targets, target_tips = _tracker_targets(tracker, robot, to_m, tip)
    normals, acceptance = _reflector_axes(tracker, len(targets), to_rad)

    touch = _touch(doc.sub("touch"), to_m, to_rad) if doc.has("touch") else None
    ballbar = _ballbar(doc.sub("ballbar"), to_m, to_rad) if doc.has("ballbar") else None
    static = _static_camera(doc.sub("static_camera"), to_m, to_rad) if doc.has("static_camera") else None
    contact = _contact(doc.sub("contact"), robot, to_m, to_rad) if doc.has("contact") else None
    seen = _self_observation(doc.sub("self_observation"), robot, to_m, to_rad) if doc.has("self_observation") else None
    if seen is not None and contact is None:
        raise doc.error("self_observation", "is simulated in a cell of contacts (a robot measuring itself) only")
    setups = [key for key, setup in (("camera", camera), ("touch", touch), ("ballbar", ballbar),
              ("static_camera", static), ("contact", contact)) if setup is not None]  # fmt: skip
    if len(setups) > 1:
        raise doc.error(setups[1], f"a cell has one of camera, touch, ballbar and static_camera; got {setups}")
    noise = doc.sub("noise", {})
    pert = doc.sub("perturbation", {})
    mass_scale = pert.number("mass_scale", 0.0, nonnegative=True)
    if mass_scale >= 1.0 or (mass_scale and not robot.mass_groups):
        raise pert.error("mass_scale", "a half-width below 1, for a robot whose file declares mass_groups")
    compliance = pert.vector("compliance", 2, [1e-6, 1e-5])
    if not 0 <= compliance[0] <= compliance[1]:
        raise pert.error("compliance", "expected [low, high] with 0 <= low <= high, rad/(N m)")
    joints = tuple(int(j) for j in pert.items("compliant_joints", list(default_compliant_joints(robot.n_links))))
    for j in joints:
        if not 1 <= j <= robot.n_links:
            raise pert.error("compliant_joints", f"joint {j} does not exist on a {robot.n_links}-joint robot")

    motion = _motion_truth(doc, robot.n_joints, to_rad)
    if motion is not None:
        if touch is not None or ballbar is not None or static is not None or contact is not None:
            raise doc.error("motion_history", "is simulated in tracker and flange-camera cells only")
        robot = robot.with_model("DH,s,e,h")

    design = doc.sub("design", {})
    standoff = design.vector("standoff", 2, [0.3 / to_m, 0.5 / to_m], to_m)
    if not 0 < standoff[0] <= standoff[1]:
        raise design.error("standoff", "expected [near, far] with 0 < near <= far")
    design_kind = design.string("kind", "seed" if camera is not None else "space_filling", DESIGNS)
    if touch is not None or ballbar is not None:
        design_kind = "touch" if touch is not None else "ballbar"
    if camera is None and design_kind == "seed":
        raise design.error("kind", "the seed design looks at the objects: a tracker cell (no camera) is space_filling")
    cell = Cell(
        name=doc.string("name"),
        source=str(path),
        robot_reference=robot_ref,
        robot=robot,
        fixture_pose=_pose(doc, "fixture", to_m, to_rad),
        sides=sides,
        camera=camera,
        tracker_pose=_pose(tracker, "pose", to_m, to_rad),
        tracker_targets=np.array(targets),
        tracker_target_tips=target_tips,
        tracker_normals=normals,
        tracker_acceptance_rad=acceptance,
        link_radii_m=_link_radii(tracker, to_m),
        tip=tip,
        camera_point_sigma_m=noise.number("camera_point_sigma", 1e-4 / to_m, to_m, nonnegative=True),
        pixel_sigma_px=noise.number("pixel_sigma_px", 0.1, nonnegative=True),
        tracker_sigma_m=noise.number("tracker_sigma", 1e-5 / to_m, to_m, nonnegative=True),
        touch=touch,
        touch_sigma_m=noise.number("touch_sigma", 1e-5 / to_m, to_m, nonnegative=True),
        spacing_sigma_m=noise.number("spacing_sigma", 5e-6 / to_m, to_m, nonnegative=True),
        tracker_probe=_pose(tracker, "probe", to_m, to_rad) if tracker.has("probe") else None,
        tracker_angle_sigma_rad=noise.number("tracker_angle_sigma", 1e-4 / to_rad, to_rad, nonnegative=True),
        ballbar=ballbar,
        distance_sigma_m=noise.number("distance_sigma", 2e-6 / to_m, to_m, nonnegative=True),
        static_camera=static,
        contact=contact,
        self_observation=seen,
        contact_sigma_m=noise.number("contact_sigma", 5e-6 / to_m, to_m, nonnegative=True),
        motion=motion,
        # A tracker section declares one; a cell with no other instrument is a tracker cell.
        has_tracker=doc.has("tracker") or not setups,
        perturbation=Perturbation(
            length_m=pert.number("length", 5e-3 / to_m, to_m, nonnegative=True),
            angle_rad=pert.number("angle", 2e-3 / to_rad, to_rad, nonnegative=True),
            distortion_rad=pert.number("distortion", 2e-3 / to_rad, to_rad, nonnegative=True),
            compliance_range=(float(compliance[0]), float(compliance[1])),
            compliant_joints=joints,
            base_length_m=pert.number("base_length", 5e-3 / to_m, to_m, nonnegative=True),
            base_angle_rad=pert.number("base_angle", 2e-3 / to_rad, to_rad, nonnegative=True),
            base_tilt_rad=pert.number("base_tilt", 0.0, to_rad, nonnegative=True),
            tool_length_m=pert.number("tool_length", 1e-3 / to_m, to_m, nonnegative=True),
            tool_angle_rad=pert.number("tool_angle", 1e-3 / to_rad, to_rad, nonnegative=True),
            mass_scale=mass_scale,
        ),
        design=Design(
            kind=design_kind,
            n_configurations=design.integer("n_configurations", 300, minimum=1, maximum=MAX_CONFIGURATIONS),
            blocks_per_side=design.integer("blocks_per_side", 3, minimum=1, maximum=1000),
            views_per_block=design.integer("views_per_block", 2, minimum=1, maximum=1000),
            standoff_m=(float(standoff[0]), float(standoff[1])),
            max_view_angle_rad=design.number("max_view_angle", 30.0 * np.pi / 180 / to_rad, to_rad, positive=True),
        ),
    )
    validation = tuple(str(v) for v in doc.items("validation", []))
    for name in validation:
        if name not in cell.instruments:
            raise doc.error(
                "validation", f"{name!r} is not one of the cell's instruments ({', '.join(cell.instruments)})"
            )
    if validation and set(validation) >= set(cell.instruments):
        raise doc.error("validation", "leaves no instrument to calibrate with")
    return replace(cell, validation=validation)


def _tracker_targets(
    tracker: Fields, robot: Robot, to_m: float, default_tip: str
) -> tuple[list[np.ndarray], tuple[str, ...]]:
    """``tracker.targets``: reflectors on the cell's tip (the flange) ``[[x, y, z], ...]``, or on
    the tips of a tree ``{tip: [[x, y, z], ...]}`` (Robot.tip_names); and each one's tip (empty:
    all on the flange)."""
    raw = tracker.raw("targets", [[0, 0, 0.1 / to_m]])
    groups = raw.items() if isinstance(raw, dict) else [(None, raw)]
    targets, tips = [], []
    for tip, points in groups:
        where = "targets" if tip is None else f"targets.{tip}"
        if tip is not None and robot.tip_error(str(tip)):
            raise tracker.error(where, robot.tip_error(str(tip)))
        tip = robot.flange_name if tip == "flange" else tip
        if not isinstance(points, list):
            raise tracker.error(where, f"expected a list of [x, y, z] points, got {points!r}")
        for i, point in enumerate(points):
            targets.append(
                Fields({"t": point}, tracker.source, tracker.path(f"{where}[{i}]")).vector("t", 3, scale=to_m)
            )
            tips.append(default_tip if tip is None else str(tip))
    if not targets:
        raise tracker.error("targets", "at least one reflector on the flange (the tracker has nothing to measure)")
    return targets, tuple(tips) if set(tips) != {robot.flange_name} else ()


def _per_target(tracker: Fields, key: str) -> list[tuple[str, object]]:
    """``tracker.<key>`` given as ``tracker.targets`` is: a list in the targets' order, or
    ``{tip: [...]}`` in the same tips and order; (field path, value) per target."""
    raw, shape = tracker.raw(key), tracker.raw("targets", None)
    groups = raw.items() if isinstance(raw, dict) else [(None, raw)]
    if isinstance(shape, dict) != isinstance(raw, dict) or (isinstance(raw, dict) and list(raw) != list(shape or {})):
        raise tracker.error(key, "give it as targets is given: a list, or the same {tip: [...]} mapping")
    out = []
    for tip, values in groups:
        where = key if tip is None else f"{key}.{tip}"
        if not isinstance(values, list):
            raise tracker.error(where, f"expected a list, one per reflector, got {values!r}")
        out += [(f"{where}[{i}]", value) for i, value in enumerate(values)]
    return out


def _link_radii(tracker: Fields, to_m: float) -> np.ndarray | None:
    """``tracker.link_radii``: the robot's bodies' radii (length unit), or None."""
    if not tracker.has("link_radii"):
        return None
    raw = tracker.raw("link_radii")
    if not isinstance(raw, list) or not raw:
        raise tracker.error("link_radii", "a list of radii, one per segment between consecutive frames")
    radii = np.array([to_float(v, tracker.source, tracker.path(f"link_radii[{i}]")) for i, v in enumerate(raw)]) * to_m
    if np.any(radii < 0):
        raise tracker.error("link_radii", "radii of 0 or more")
    return radii


def _reflector_axes(tracker: Fields, n_targets: int, to_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """``tracker.normals`` (each reflector's axis in its tip's frame, as targets are listed;
    default z) and ``tracker.acceptance`` (the acceptance half-angle in the angle unit: one
    number for all, or one per reflector; default REFLECTOR_ACCEPTANCE_DEG)."""
    normals = np.tile([0.0, 0.0, 1.0], (n_targets, 1))
    if tracker.has("normals"):
        given = _per_target(tracker, "normals")
        if len(given) != n_targets:
            raise tracker.error("normals", f"one per reflector: {n_targets} targets, {len(given)} normals")
        for i, (where, value) in enumerate(given):
            v = Fields({"n": value}, tracker.source, tracker.path(where)).vector("n", 3)
            if np.linalg.norm(v) < 1e-9:
                raise tracker.error(where, "a direction, not zero")
            normals[i] = v / np.linalg.norm(v)
    acceptance = np.full(n_targets, np.radians(REFLECTOR_ACCEPTANCE_DEG))
    if tracker.has("acceptance"):
        raw = tracker.raw("acceptance")
        given = (
            [("acceptance", raw)] * n_targets
            if not isinstance(raw, (list, dict))
            else _per_target(tracker, "acceptance")
        )
        if len(given) != n_targets:
            raise tracker.error("acceptance", f"one number, or one per reflector: {n_targets} targets, {len(given)}")
        for i, (where, value) in enumerate(given):
            angle = Fields({"a": value}, tracker.source, tracker.path(where)).number("a", scale=to_rad, positive=True)
            if angle > np.pi / 2:
                raise tracker.error(where, "a reflector's acceptance half-angle: at most 90 deg")
            acceptance[i] = angle
    return normals, acceptance
