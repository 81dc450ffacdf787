"""The schema of a simulated cell (docs/formats.md, "Cell"); load_cell validates a cell here first
and checks what depends on the robot (a tip, a joint's number, the motion history's length) after.
Lengths and angles in the cell's units (default m, rad)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from ..core.schema import NUMBER_JSON, Number, Pose, Schema, Units, checked, choice, numbers, refuse, to_number, vector
from ..model.schema import Camera, Intrinsics, Payload, RobotReference
from . import MAX_CONFIGURATIONS

SIDES = ("+x", "-x", "+y", "-y", "+z", "-z")
LENGTH = "the cell's length unit"
ANGLE = "the cell's angle unit"


class CuboidObject(Schema):
    """A cuboid calibration object on the fixture; its listed sides carry grids of points."""

    name: str
    size: vector(3) = Field(description=f"edge lengths, {LENGTH}")
    pose: Pose = Field(None, description="the object on the fixture")
    sides: list[choice(SIDES, "side", str(SIDES))]


class Grid(Schema):
    pitch: Number = Field(None, gt=0, description=f"the grid's pitch, {LENGTH} (default 40 mm)")
    margin: Number = Field(None, ge=0, description=f"from a side's edge, {LENGTH} (default the pitch)")


def _targets(value: Any) -> Any:
    groups = value.items() if isinstance(value, dict) else [(None, value)]
    for tip, points in groups:
        where = "" if tip is None else str(tip)
        if not isinstance(points, list):
            raise refuse(f"expected a list of [x, y, z] points, got {points!r}", where)
        for i, point in enumerate(points):
            at = f"{where}[{i}]"
            if not isinstance(point, list) or len(point) != 3:
                raise refuse(f"expected a list of 3 numbers, got {point!r}", at)
            for k, v in enumerate(point):
                to_number(v, f"{at}[{k}]")
    return value


_POINTS = {"type": "array", "items": {"type": "array", "items": NUMBER_JSON, "minItems": 3, "maxItems": 3}}
Targets = checked(
    _targets,
    {
        "description": f"reflectors [[x, y, z], ...] on the cell's tip ({LENGTH}), or {{tip: [[x, y, z], ...]}} on "
        "the tips of a tree",
        "anyOf": [_POINTS, {"type": "object", "additionalProperties": _POINTS}],
    },
)


Normals = checked(
    _targets,
    {
        "description": "each reflector's axis in its tip's frame, listed as targets are (default z)",
        "anyOf": [_POINTS, {"type": "object", "additionalProperties": _POINTS}],
    },
)


def _acceptance(value: Any) -> Any:
    entries = value if isinstance(value, list) else list(value.values()) if isinstance(value, dict) else [value]
    for i, entry in enumerate(entries):
        for k, v in enumerate(entry if isinstance(entry, list) else [entry]):
            to_number(v, f"[{i}][{k}]" if isinstance(entry, list) else f"[{i}]")
    return value


Acceptance = checked(
    _acceptance,
    {
        "description": "a reflector's acceptance half-angle (the file's angle unit; default 30 deg): one number, "
        "or one per reflector, listed as targets are",
        "anyOf": [NUMBER_JSON, {"type": "array", "items": NUMBER_JSON},
                  {"type": "object", "additionalProperties": {"type": "array", "items": NUMBER_JSON}}],
    },
)  # fmt: skip


class Tracker(Schema):
    pose: Pose = Field(None, description="the tracker in the world frame W")
    targets: Targets = None
    probe: Pose = Field(None, description="a 6-DoF probe on the flange (tracker poses)")
    normals: Normals = None
    acceptance: Acceptance = None
    link_radii: list[Number] = Field(
        None, description=f"{LENGTH}: the robot's own bodies, one capsule per segment between consecutive frames' "
        "origins (base to flange), each this radius; a reflector whose line to the tracker passes through one is not "
        "seen (fgcal plan)",
    )  # fmt: skip


class NamedPoint(Schema):
    name: str
    xyz: vector(3) = Field(description=LENGTH)


class Touch(Schema):
    probe: vector(3) = Field(description=f"the probe's tip on the flange, {LENGTH}")
    points: list[NamedPoint] = Field(description="the sockets touched, at least 3")
    touches_per_point: int = Field(12, ge=3, le=1000)
    max_tilt: Number = Field(None, gt=0, description=f"{ANGLE} (default 40 deg)")
    known_distances: bool = Field(True, description="whether the sockets' spacings are known")


class Between(Schema):
    readings: int = Field(ge=6, le=MAX_CONFIGURATIONS // 2, description="ballbar readings between configuration pairs")
    centre: vector(3) = Field(description=LENGTH)
    radius: Number = Field(ge=0, description=LENGTH)


class Ballbar(Schema):
    ball: vector(3) = Field(description=f"the tool ball on the flange, {LENGTH}")
    pivots: list[NamedPoint] = None
    length: vector(2) = Field(description=f"[shortest, longest] bar, {LENGTH}")
    readings_per_pivot: int = Field(40, ge=6, le=1000)
    max_tilt: Number = Field(None, gt=0, description=f"{ANGLE} (default 45 deg)")
    between_configurations: Between = None


class ContactBall(Schema):
    name: str
    tip: str = Field(description="the robot's tip (or flange) the ball is on")
    xyz: vector(3) = Field(description=f"the ball's centre on its tip (the drawing's), {LENGTH}")
    radius: Number = Field(gt=0, description=LENGTH)


class ContactPlane(Schema):
    name: str
    normal: vector(3) = Field(description="its nominal normal in W, towards the robot: a unit vector (within 1e-6)")
    offset: Number = Field(description=f"its nominal distance from W's origin along the normal, {LENGTH}")


class TipGauge(Schema):
    """A ballbar between the first two balls (the hands hold it), read at many configurations."""

    length: Number = Field(gt=0, description=f"the bar's length at the middle of its travel, {LENGTH}")
    travel: Number = Field(gt=0, description=f"its full travel, {LENGTH}")
    readings: int = Field(100, ge=1, le=MAX_CONFIGURATIONS // 2)


class Hold(Schema):
    """Joints held still while the robot touches itself (a torso locked: its errors are then one
    rigid motion of both arms, which self-contact cannot see and its score removes)."""

    joints: list[int] = Field(description="1-based joint numbers (the configurations' q columns)")
    at: numbers() = Field(description=f"their values, one per joint, {ANGLE}")


class Contact(Schema):
    """Contact elements (balls on the tips of a tree) touching each other and planes of the cell."""

    elements: list[ContactBall] = Field(description="at least one; self-contacts join the first two")
    planes: list[ContactPlane] = None
    self_contacts: int = Field(40, ge=0, le=MAX_CONFIGURATIONS // 2, description="contacts of the first two balls")
    plane_contacts: int = Field(12, ge=0, le=1000, description="contacts of each ball with each plane")
    centre_error: Number = Field(None, ge=0, description=f"the true centres off the drawing's, {LENGTH} (default 1 mm)")
    plane_angle_error: Number = Field(
        None, ge=0, description=f"the true planes' tilt off nominal, {ANGLE} (default 1 deg)"
    )
    plane_offset_error: Number = Field(None, ge=0, description=f"the true planes off nominal, {LENGTH} (default 5 mm)")
    position_sigma: Number = Field(None, gt=0, description=f"the dataset's prior on a centre, {LENGTH} (default 2 mm)")
    gauge: TipGauge = Field(None, description="a ballbar between the first two balls (tip_distances)")
    hold: Hold = None


class LinkCamera(Schema):
    name: str
    joint: int = Field(ge=0, description="the link (1-based joint; 0 the base) whose frame carries it")
    mounting: Pose = Field(description="its pose on the link (the drawing's)")
    image_size: vector(2) = Field(description="px")
    intrinsics: Intrinsics
    distortion: vector(5) = [0.0] * 5


class TipBoard(Schema):
    name: str
    tip: str = Field(description="the robot's tip (or flange) carrying it")
    pose: Pose = Field(description="its pose on the tip (the drawing's), its frame at its centre")
    corners: vector(2) = Field(description="inner corners (columns, rows), integers >= 2")
    square: Number = Field(gt=0, description=LENGTH)


class SelfObservation(Schema):
    """Cameras on a link seeing checkerboards on the tips (observed_pixels)."""

    cameras: list[LinkCamera]
    boards: list[TipBoard]
    views: int = Field(200, ge=1, le=MAX_CONFIGURATIONS // 2, description="configurations where a camera sees a board")
    mounting_error: vector(2) = Field(None, description=f"the true mountings and boards off the drawing's: [{LENGTH}, "
                                      f"{ANGLE}] (default 2 mm, 1 deg)")  # fmt: skip
    max_view_angle: Number = Field(None, gt=0, description=f"{ANGLE} (default 60 deg)")


class StaticBoard(Schema):
    mount: Pose = Field(None, description="the board on the flange")
    corners: vector(2) = Field(description="inner corners (columns, rows), integers >= 2")
    square: Number = Field(gt=0, description=LENGTH)


class StaticCamera(Schema):
    pose: Pose = Field(None, description="the camera in the world frame W")
    image_size: vector(2) = Field(description="px")
    intrinsics: Intrinsics
    distortion: vector(5) = [0.0] * 5
    board: StaticBoard
    max_view_angle: Number = Field(None, gt=0, description=f"{ANGLE} (default 60 deg)")


class CellNoise(Schema):
    """The simulated instruments' noise (sigma per coordinate)."""

    camera_point_sigma: Number = Field(None, ge=0, description=f"{LENGTH} (default 0.1 mm)")
    pixel_sigma_px: Number = Field(0.1, ge=0, description="px")
    tracker_sigma: Number = Field(None, ge=0, description=f"{LENGTH} (default 10 um)")
    tracker_angle_sigma: Number = Field(None, ge=0, description=f"{ANGLE} (default 0.1 mrad)")
    touch_sigma: Number = Field(None, ge=0, description=f"{LENGTH} (default 10 um)")
    spacing_sigma: Number = Field(None, ge=0, description=f"{LENGTH} (default 5 um)")
    distance_sigma: Number = Field(None, ge=0, description=f"{LENGTH} (default 2 um)")
    contact_sigma: Number = Field(
        None, ge=0, description=f"{LENGTH}: how far from touching a contact closes (default 5 um)"
    )


class Perturbation(Schema):
    """How far the simulated true robot is from the nominal one (half-widths, uniform)."""

    length: Number = Field(None, ge=0, description=f"{LENGTH} (default 5 mm)")
    angle: Number = Field(None, ge=0, description=f"{ANGLE} (default 2 mrad)")
    distortion: Number = Field(None, ge=0, description=f"{ANGLE} (default 2 mrad)")
    compliance: vector(2) = Field(None, description="[low, high], rad/(N m)")
    compliant_joints: list[int] = Field(None, description="1-based joints (default 1-3)")
    base_length: Number = Field(None, ge=0, description=LENGTH)
    base_angle: Number = Field(None, ge=0, description=ANGLE)
    base_tilt: Number = Field(None, ge=0, description=ANGLE)
    tool_length: Number = Field(None, ge=0, description=LENGTH)
    tool_angle: Number = Field(None, ge=0, description=ANGLE)
    mass_scale: Number = Field(0.0, ge=0, description="half-width of the mass scales (below 1; needs mass_groups)")


class MotionHistory(Schema):
    """Lost motion and speed-dependent deflection of the simulated robot, per joint."""

    lost_motion: numbers() = Field(None, description=f"one per joint, {ANGLE}")
    speed: numbers() = Field(None, description=f"one per joint, {ANGLE}")
    approach: Literal["previous", "from_below"] = "previous"
    approach_offset: Number = Field(None, gt=0, description=f"{ANGLE} (default 2 deg)")


class Design(Schema):
    kind: Literal["seed", "space_filling"] = Field(None, description="default seed with a camera, else space_filling")
    n_configurations: int = Field(300, ge=1, le=MAX_CONFIGURATIONS)
    blocks_per_side: int = Field(3, ge=1, le=1000)
    views_per_block: int = Field(2, ge=1, le=1000)
    standoff: vector(2) = Field(None, description=f"[near, far] camera distance, {LENGTH}")
    max_view_angle: Number = Field(None, gt=0, description=f"{ANGLE} (default 30 deg)")


class CellFile(Schema):
    """A simulated cell (fgcal simulate): the robot, its instruments, their noise and the truth's spread."""

    name: str
    robot: RobotReference
    units: Units = None
    base: Pose = Field(None, description="the robot's base in W (default the robot file's)")
    fixture: Pose = Field(None, description="the fixture (calibration objects) in W")
    objects: list[CuboidObject] = None
    grid: Grid = None
    camera: Camera = None
    payload: Payload = None
    tracker: Tracker = None
    tip: str = Field(None, description="the robot's tip that carries the targets (default the flange)")
    touch: Touch = None
    ballbar: Ballbar = None
    static_camera: StaticCamera = None
    contact: Contact = None
    self_observation: SelfObservation = None
    validation: list[str] = Field(
        None,
        description="instruments measured for validation only: the suggested config fits the cell's other "
        "instruments as one set each and scores on these (e.g. [tracker])",
    )
    noise: CellNoise = None
    perturbation: Perturbation = None
    motion_history: MotionHistory = None
    design: Design = None
    notes: Any = None
