"""The schemas of a dataset's header (dataset.yaml) and of an import mapping (fgcal import-csv);
docs/formats.md. The loaders validate a document here first; what needs the files or the robot
(a table's columns, a tip of the robot, a target measured) they check after."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from ..core.noise import NoiseSection
from ..core.schema import Label, Number, Pose, Schema, Units, checked, choice, constant, one_or_more, refuse, vector
from ..model.boards import DICTIONARY
from ..model.schema import Camera, Intrinsics, RobotReference

DATASET_FORMAT = "fgcal-dataset/1"
IMPORT_FORMAT = "fgcal-import/1"
MEASURED = ("camera_points", "pixels", "tracker_points", "tracker_references", "touch_points", "point_distances",
            "tracker_poses", "distances", "tool_distances", "contacts", "plane_contacts",
            "tip_distances", "observed_pixels")  # fmt: skip
ORDER = "the configurations' order: measured (the rows are the measurement order; motion history) or unknown"


class Files(Schema):
    """The dataset's tables (CSV files in its folder)."""

    configurations: str = Field(description="config, q1..qn (joint units), optional approach and speed columns")
    points: str = Field(None, description="the objects' drawings: point, object, side, x, y, z")
    camera_points: str = None
    pixels: str = None
    tracker_points: str = None
    tracker_references: str = None
    touch_points: str = None
    point_distances: str = None
    tracker_poses: str = None
    distances: str = None
    tool_distances: str = None
    contacts: str = Field(None, description="config, element_a, element_b: two contact elements touch")
    plane_contacts: str = Field(None, description="config, element, plane: a contact element touches a plane")
    tip_distances: str = Field(None, description="config, element_a, element_b, distance: a gauge between two balls")
    observed_pixels: str = Field(None, description="config, camera, board, point, u, v: a link camera sees a board")


class Board(Schema):
    """A ChArUco board on an object's side."""

    name: str
    squares: vector(2) = Field(description="squares along x and y")
    square: Number = Field(gt=0, description="a square's side, in the dataset's length unit")
    first_id: int = Field(ge=0, description="the board's first ArUco id")
    pose: Pose = Field(description="the board on the fixture")
    corners: list[Label] = Field(description="the inner corners' point names, (squares_x - 1) * (squares_y - 1)")


class Markers(Schema):
    dictionary: Literal[DICTIONARY] = Field(DICTIONARY, description="the ArUco dictionary (the only one fgcal reads)")
    marker_ratio: Number = Field(None, gt=0, description="a marker's side over a square's")
    boards: list[Board]


class Tracker(Schema):
    targets: list[Label] = Field(description="the reflectors' names (the tracker_points table's targets)")
    tips: dict[str, str] = Field(None, description="a tree: {target: tip} for targets not on the dataset's tip")


class ContactElement(Schema):
    """A ball on a tip of the robot (its drawing's values: the calibration's priors)."""

    tip: str = Field(description="the robot's tip (or flange) the ball is fixed to")
    xyz: vector(3) = Field(description="the ball's centre in the tip's frame")
    radius: Number = Field(gt=0, description="the ball's radius")


class ContactPlane(Schema):
    """A plane of the cell a contact element touches (a table, a wall): ``n . x = offset`` in W,
    the ball on the side ``normal`` points to."""

    normal: vector(3) = Field(description="its nominal normal in W: a unit vector (within 1e-6)")
    offset: Number = Field(description="its nominal distance from W's origin along the normal")


class Contact(Schema):
    """The contact elements and planes of a robot measuring itself by contact."""

    elements: dict[str, ContactElement] = Field(description="by name: the contacts tables' elements")
    planes: dict[str, ContactPlane] = Field(None, description="by name: the plane_contacts table's planes")
    position_sigma: Number = Field(
        None, gt=0, description="prior sigma of an element's centre about its drawing's (default 2 mm)"
    )
    radius_sigma: Number = Field(
        None, gt=0, description="prior sigma of a radius about its drawing's (default 2 um: a gauge ball's tolerance)"
    )
    plane_angle_sigma: Number = Field(
        None, gt=0, description="prior sigma of a plane's normal about the nominal, angle unit (default: no prior)"
    )
    plane_offset_sigma: Number = Field(
        None, gt=0, description="prior sigma of a plane's offset about the nominal (default: no prior)"
    )


class LinkCamera(Schema):
    """A camera on a link of the robot (self-observation): its image and intrinsics (known)."""

    joint: int = Field(ge=0, description="the link (1-based joint number; 0 the base) whose frame carries it")
    mounting: Pose = Field(description="its nominal pose on the link (T_link_C): the calibration's start")
    image_size: vector(2) = Field(description="width and height, px")
    intrinsics: Intrinsics
    distortion: vector(5) = Field([0.0] * 5, description="OpenCV's k1, k2, p1, p2, k3")


class TipBoard(Schema):
    """A checkerboard on a tip of the robot (self-observation)."""

    tip: str = Field(description="the robot's tip (or flange) carrying it")
    pose: Pose = Field(description="its nominal pose on the tip (T_tip_B, its frame at its centre): the start")
    corners: vector(2) = Field(description="inner corners (columns, rows), integers >= 2; points c00, c01, ...")
    square: Number = Field(gt=0, description="a square's side")


class SelfObservation(Schema):
    """Cameras on links of the robot seeing boards on its tips (the observed_pixels table)."""

    cameras: dict[str, LinkCamera]
    boards: dict[str, TipBoard]


class DatasetPayload(Schema):
    mass: Number = Field(ge=0, description="kg")
    com: vector(3) = Field([0.0, 0.0, 0.0], description="on the flange, the dataset's length unit")


class DatasetHeader(Schema):
    """A dataset's header, dataset.yaml. Lengths and angles in its units (default m, rad)."""

    format: constant(DATASET_FORMAT) = Field(description=f"always {DATASET_FORMAT}")
    robot: RobotReference
    units: Units = None
    measured: list[choice(MEASURED, "measurement kind", str(MEASURED))] = Field(
        description="the measurement tables the dataset holds"
    )
    files: Files
    camera: Camera = None
    payload: DatasetPayload = None
    fixture: Pose = Field(None, description="the fixture (calibration objects) in the world frame W")
    images: str = Field(None, description="folder of the camera images, <config>.png")
    markers: Markers = Field(None, description="the ChArUco boards the images show (with images)")
    tracker: Tracker = None
    contact: Contact = Field(None, description="contact elements (balls on tips) and planes (contacts tables)")
    self_observation: SelfObservation = Field(None, description="cameras on links seeing boards on tips")
    tip: str = Field(None, description="the robot's tip that carries the measured point(s); default the flange")
    noise: NoiseSection = Field(None, description="what the instrument states")
    order: Literal["measured", "unknown"] = Field("measured", description=ORDER)
    source: str = Field(None, description="free text: simulation seed, converter, instrument")
    notes: Any = None


def _column(value: Any) -> Any:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise refuse(f"expected a column name or number, got {value!r}")
    return value


Column = checked(_column, {"type": ["string", "integer"], "description": "a column's name, or its 1-based number"})


def _not_found(value: Any) -> Any:
    if not isinstance(value, list) or not all(isinstance(t, (str, int, float)) and not isinstance(t, bool)
                                              for t in value):  # fmt: skip
        raise refuse(f"expected a list of cell texts, got {value!r}")
    return value


NotFound = checked(
    _not_found,
    {
        "type": "array",
        "items": {"type": ["string", "number"]},
        "description": "cell texts that mean 'not measured' (-999, NaN), besides the empty cell",
    },
)


class Read(Schema):
    """How a table mapping reads its file."""

    file: str = Field(description="the CSV (or text) file, relative to the mapping")
    delimiter: Literal[",", ";", "tab", "whitespace"] = Field(None, description="default: guessed from the first line")
    decimal: Literal[".", ","] = "."
    header: bool = Field(True, description="whether the first row names the columns")
    skip_rows: int = Field(0, ge=0)
    encoding: str = "utf-8-sig"
    units: Units = Field(None, description="this file's units, if not the mapping's")
    not_found: NotFound = None


class Measured(Read):
    zeros_mean_not_found: bool = Field(False, description="a row of zeros is a reflector out of sight")


class ConfigurationsTable(Read):
    config: Column = Field(None, description="the id column (default: c0000, c0001, ...)")
    joints: list[Column] = Field(description="one column per joint")
    approach: list[Column] = Field(None, description="each move's approach point, one column per joint")
    speed: Column = Field(None, description="each move's speed factor")


class PointsTable(Measured):
    config: Column = None
    target: Column = None
    target_name: str = Field(None, description="one target's name for every row (instead of a target column)")
    xyz: list[Column] = Field(description="three columns")


class PosesTable(Measured):
    config: Column = None
    xyz: list[Column] = Field(description="three columns")
    quaternion: list[Column] = Field(None, description="four columns: w, x, y, z")
    euler: Euler = None


class Euler(Schema):
    columns: list[Column] = Field(description="three columns, in the mapping's angle unit")
    sequence: str = Field(description="scipy's: xyz (fixed axes) or XYZ (moving axes), ...")


class DistancesTable(Measured):
    config: Column = None
    pivot: Column = None
    pivot_name: str = None
    distance: Column


class ToolDistancesTable(Measured):
    # Both are needed (the loader says so naming config_a): a distance joins two configurations.
    config_a: Column = Field(None, description="the first configuration's column (needed)")
    config_b: Column = Field(None, description="the second configuration's column (needed)")
    distance: Column


class ImportMapping(Schema):
    """An import mapping (fgcal import-csv): which columns of which files are which dataset table."""

    format: constant(IMPORT_FORMAT) = Field(description=f"always {IMPORT_FORMAT}")
    robot: RobotReference
    units: Units = None
    configurations: ConfigurationsTable
    tracker_points: one_or_more(PointsTable) = None
    tracker_references: one_or_more(PointsTable) = None
    tracker_poses: one_or_more(PosesTable) = None
    distances: one_or_more(DistancesTable) = None
    tool_distances: one_or_more(ToolDistancesTable) = None
    payload: DatasetPayload = None
    order: Literal["measured", "unknown"] = Field("measured", description=ORDER)
    tip: str = None
    target_tips: dict[str, str] = None
    source: str = None
    notes: Any = None


PosesTable.model_rebuild()
