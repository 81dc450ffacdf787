"""Measurement datasets: a directory with ``dataset.yaml`` (header) and CSV tables.

Header fields (documented in docs/formats.md)::

    format: fgcal-dataset/1
    robot: kuka_kr125_2            # bundled name, or a robot file relative to this directory
    units: {length: m, angle: rad} # of every table in this dataset
    measured: [camera_points, pixels, tracker_points]
    files: {configurations: configurations.csv, points: points.csv, ...}
    camera: {image_size, intrinsics, distortion, mounting: {xyz, rpy}}   # when a camera was used
    payload: {mass, com}           # kg; com in the flange frame (gravity moments need it)
    fixture: {xyz, rpy}            # nominal T_W_F of the calibration objects (drawing)
    tracker: {targets: [names]}    # when a tracker was used; on a tree, tips: {target: tip name}
    tip: name                      # a tree: the tip carrying what is measured (default the flange)
    noise: {tracker_sigma: 1.5e-5, ...}  # the instrument's stated noise (a calibration config's noise keys)
    order: measured                # the configurations' rows are in measurement order (default), or unknown
    source: free text (simulation seed, converter, instrument)

Tables (first row is the header; ``config`` refers to ``configurations.csv``):

- configurations: ``config, q1..qn`` (joint angles), in the order they were measured; optionally
  ``before_q1..before_qn`` (the joint values the robot came from, when it was not the previous
  row: an approach point; empty cells: the previous row) and ``speed`` (the move's speed factor,
  1 by default): the motion history (fgcal.model.motion)
- points: ``point, object, side, x, y, z`` (calibration points in the fixture frame F)
- camera_points: ``config, point, x, y, z`` (point measured in the camera frame)
- pixels: ``config, point, u, v`` (px)
- tracker_points: ``config, target, x, y, z`` (tool target in the tracker frame)
- tracker_references: ``config, target, x, y, z`` (fixed targets in the cell, stability check)
- touch_points: ``config, point`` (the tool's probe sits at the fixed point ``point``: a socket)
- point_distances: ``point_a, point_b, distance`` (known distances between touch points)
- tracker_poses: ``config, x, y, z, qw, qx, qy, qz`` (a 6D probe's pose in the tracker frame,
  or a board's pose in a camera: position and unit quaternion)
- distances: ``config, pivot, distance`` (a ballbar from the tool ball to the fixed pivot)
- tool_distances: ``config_a, config_b, distance`` (between the tool ball at two configurations)
- contacts: ``config, element_a, element_b`` (two contact elements of dataset.yaml contact touch)
- plane_contacts: ``config, element, plane`` (a contact element touches a plane of dataset.yaml contact)
- tip_distances: ``config, element_a, element_b, distance`` (a gauge between two contact elements' centres)
- observed_pixels: ``config, camera, board, point, u, v`` (a camera on a link sees a board's point on a tip)
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import InputError
from ..core.fields import Fields, check_name, first_repeat, is_plain_number, read_file_text, read_yaml
from ..core.noise import stated_noise
from ..core.outputs import write_text
from ..core.schema import validate
from ..core.se3 import pose_from_xyz_rpy
from ..core.units import Units, parse_units
from ..model.boards import SideBoard
from ..model.camera import Camera, parse_camera
from ..model.motion import MotionHistory, features
from ..model.robot import Robot
from ..model.robot_io import referenced_robot
from .schema import DATASET_FORMAT, MEASURED, DatasetHeader

FORMAT = DATASET_FORMAT
ORDERS = ("measured", "unknown")
MAX_SPEED_FACTOR = 100.0
# table name -> (id columns, numeric columns, kind of numeric columns)
TABLES = {
    "points": (("point", "object", "side"), ("x", "y", "z"), "length"),
    "camera_points": (("config", "point"), ("x", "y", "z"), "length"),
    "pixels": (("config", "point"), ("u", "v"), "pixel"),
    "tracker_points": (("config", "target"), ("x", "y", "z"), "length"),
    "tracker_references": (("config", "target"), ("x", "y", "z"), "length"),
    "touch_points": (("config", "point"), (), "length"),
    "point_distances": (("point_a", "point_b"), ("distance",), "length"),
    "tracker_poses": (("config",), ("x", "y", "z", "qw", "qx", "qy", "qz"), ("length",) * 3 + ("unitless",) * 4),
    "distances": (("config", "pivot"), ("distance",), "length"),
    "tool_distances": (("config_a", "config_b"), ("distance",), "length"),
    "contacts": (("config", "element_a", "element_b"), (), "length"),
    "plane_contacts": (("config", "element", "plane"), (), "length"),
    "tip_distances": (("config", "element_a", "element_b"), ("distance",), "length"),
    "observed_pixels": (("config", "camera", "board", "point"), ("u", "v"), "pixel"),
}
MEASUREMENTS = MEASURED  # the tables a dataset may list as measured (data.schema: one list)
# Largest magnitude a value of each kind may have (SI): far beyond any robot cell, far below
# what overflows the algebra (a 1e300 reading once hung the tracker initialisation).
LIMITS = {"length": 1e4, "pixel": 1e6, "angle": 1e3, "unitless": 1e3}
# A quaternion whose norm is this far from 1 is no rotation (rounding in an export is 1e-6).
QUATERNION_TOLERANCE = 1e-3


@dataclass
class Table:
    """Rows of one CSV table: id columns as string arrays, values (M, k) in SI; ``lines``: each
    row's line in its file (read_csv's), None where the table was not read from one."""

    ids: dict[str, np.ndarray]
    values: np.ndarray
    lines: tuple[int, ...] | None = None

    def __len__(self) -> int:
        return len(self.values)


@dataclass(frozen=True)
class ContactElement:
    """A ball on a tip (dataset.yaml contact.elements), its drawing's values (SI)."""

    tip: str
    centre: np.ndarray  # (3,) in the tip's frame
    radius: float


@dataclass(frozen=True)
class ContactSetup:
    """dataset.yaml contact: the elements and planes (nominal, SI) and the priors' sigmas."""

    elements: dict[str, ContactElement]
    planes: dict[str, tuple[np.ndarray, float]]  # name -> (unit normal in W, offset)
    position_sigma_m: float = 2e-3
    radius_sigma_m: float = 2e-6
    plane_angle_sigma_rad: float | None = None
    plane_offset_sigma_m: float | None = None


@dataclass(frozen=True)
class LinkCamera:
    """A camera on a link (dataset.yaml self_observation.cameras); the link's frame is the
    robot's tip of the camera's name (added to the dataset's robot)."""

    joint: int  # 0-based; -1 the base
    mounting: np.ndarray  # nominal T_link_C
    camera: Camera


@dataclass(frozen=True)
class TipBoard:
    """A checkerboard on a tip (dataset.yaml self_observation.boards)."""

    tip: str
    pose: np.ndarray  # nominal T_tip_B
    points: np.ndarray  # (m, 3) its inner corners in its frame (z = 0, frame at the centre)
    point_names: tuple[str, ...]


def board_corners(columns: int, rows: int, square: float) -> tuple[np.ndarray, tuple[str, ...]]:
    """A checkerboard's inner corners (m, 3) in its frame (at its centre) and their names."""
    points = np.array([[c * square, r * square, 0.0] for r in range(rows) for c in range(columns)])
    points[:, :2] -= points[:, :2].mean(axis=0)
    return points, tuple(f"c{r:02d}{c:02d}" for r in range(rows) for c in range(columns))


@dataclass
class Dataset:
    path: Path
    robot: Robot
    configs: np.ndarray  # (N,) configuration ids (str)
    q: np.ndarray  # (N, n) joint angles, rad
    tables: dict[str, Table] = field(default_factory=dict)
    camera: Camera | None = None
    camera_mounting: np.ndarray | None = None  # nominal T_n_C of a camera on the flange, as given
    fixture_pose: np.ndarray | None = None  # nominal T_W_F
    images_dir: Path | None = None  # camera images, one per configuration: <config>.png
    boards: list = field(default_factory=list)  # fgcal.model.boards.SideBoard of each marked side
    header: dict = field(default_factory=dict)
    noise: dict[str, float] = field(default_factory=dict)  # the instrument's stated sigmas (fgcal.core.noise), SI
    history: MotionHistory | None = None  # how each configuration was reached (None: in row order)
    # The tip of a tree each tracker target is on (dataset.yaml tracker.tips); absent: the flange.
    target_tips: dict[str, str] = field(default_factory=dict)
    # The tip of a tree that carries what is measured (a probe, a ball, a board, reflectors not
    # listed in tracker.tips): dataset.yaml tip; None: the flange.
    tip: str | None = None
    contact: ContactSetup | None = None  # dataset.yaml contact (contact elements and planes)
    link_cameras: dict[str, LinkCamera] = field(default_factory=dict)  # dataset.yaml self_observation
    tip_boards: dict[str, TipBoard] = field(default_factory=dict)

    @property
    def motion_history(self) -> MotionHistory:
        return self.history if self.history is not None else MotionHistory.in_order(self.q)

    @property
    def motion(self) -> np.ndarray:
        """(N, 2n) motion-history features of the configurations (fgcal.model.motion); computed on
        each call (microseconds), so that a copy with other configurations is never stale."""
        return features(self.q, self.motion_history)

    def motion_of(self, config_ids: np.ndarray) -> np.ndarray:
        """The motion features of these configurations (by id)."""
        return self.motion[self.config_index(config_ids)]

    def points_F(self) -> dict[str, np.ndarray]:
        """Calibration points by name, in the fixture frame (m)."""
        points = self.tables["points"]
        return dict(zip(points.ids["point"], points.values, strict=True))

    def config_index(self, config_ids: np.ndarray) -> np.ndarray:
        lookup = {c: i for i, c in enumerate(self.configs)}
        return np.array([lookup[c] for c in config_ids], dtype=int)


def format_float(value: float) -> str:
    """Shortest round-trip text of a float: deterministic files, no precision lost."""
    return repr(float(value))


def write_csv(
    path: Path, header: Sequence[str], rows: Sequence[Sequence[object]], comments: Sequence[str] = ()
) -> None:
    """A CSV table; ``comments`` (each a line starting with ``#``) before its header, which
    read_csv skips: what the file assumed, stated where the user keeps it."""
    if any(not line.startswith("#") or "\n" in line or "\r" in line for line in comments):
        raise ValueError(f"comment lines start with # and are one line each: {list(comments)}")
    buffer = io.StringIO()
    buffer.writelines(line + "\n" for line in comments)
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([format_float(v) if isinstance(v, (float, np.floating)) else v for v in row])
    write_text(path, buffer.getvalue())


class Rows(list):
    """A CSV file's rows after its header, with each row's line in the file (``lines``): its
    leading ``#`` comments and blank lines counted, so that an error names the line an editor
    shows."""

    def __init__(self, rows, lines) -> None:
        super().__init__(rows)
        self.lines = tuple(lines)


def line_numbers(rows) -> tuple[int, ...]:
    """The file's line of each of ``rows`` (read_csv's body, or rows made from it one for one);
    rows not read by read_csv are counted from line 2, after a header."""
    lines = getattr(rows, "lines", None)
    if lines is not None and len(lines) == len(rows):
        return tuple(lines)
    return tuple(range(2, len(rows) + 2))


def table_lines(table: Table) -> tuple[int, ...]:
    """The file's line of each of a table's rows (from line 2 where it was not read from a file)."""
    if table.lines is not None and len(table.lines) == len(table):
        return tuple(table.lines)
    return tuple(range(2, len(table) + 2))


def numbered(rows):
    """(line in the file, row) for each of ``rows`` (line_numbers)."""
    return zip(line_numbers(rows), rows, strict=True)


def read_csv(path: Path, required: Sequence[str]) -> tuple[list[str], Rows]:
    """The header and the rows (a Rows: each one's line in the file) of a CSV file; ``#``
    comment lines before the header and blank rows are skipped."""
    if not Path(path).exists():
        raise InputError(path, None, "file not found (listed in dataset.yaml files)")
    # utf-8-sig: a byte-order mark, as spreadsheet programs write, is not part of the header.
    text = read_file_text(path, "utf-8-sig")
    # Lines starting with # before the header are comments (fgcal states its outputs' assumptions there).
    skipped = 0
    while text.startswith("#"):
        text = text.partition("\n")[2]
        skipped += 1
    reader = csv.reader(io.StringIO(text, newline=""))
    rows, starts = [], []
    try:
        for row in reader:
            starts.append(skipped + (reader.line_num - row_lines(row)) + 1)
            rows.append(row)
    except csv.Error as exc:
        raise InputError(path, f"line {skipped + reader.line_num}", f"not CSV: {exc}") from None
    if not rows:
        raise InputError(path, None, "empty file: a header row is required")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(path, missing[0], f"missing column (header is {', '.join(header)})")
    kept = [k for k in range(1, len(rows)) if any(cell.strip() for cell in rows[k])]
    body = Rows([rows[k] for k in kept], [starts[k] for k in kept])
    for line, row in numbered(body):
        if len(row) != len(header):
            raise InputError(path, f"line {line}", f"expected {len(header)} columns, got {len(row)}")
    return header, body


def row_lines(row: list[str]) -> int:
    """How many lines of the file a parsed CSV row spans (a quoted field may hold line breaks)."""
    return 1 + sum(cell.count("\n") for cell in row)


def parse_numbers(
    path: Path, header: list[str], body: list[list[str]], columns: Sequence[str], kind: str, to_si: float
) -> np.ndarray:
    """The columns as floats in SI: plain decimal numbers only (``float`` would also take
    ``1_000``, full-width digits and ``nan``), finite and within LIMITS[kind]."""
    out = np.empty((len(body), len(columns)))
    lines = line_numbers(body)
    for j, col in enumerate(columns):
        c = header.index(col)
        for i, row in enumerate(body):
            text = row[c].strip()
            if not is_plain_number(text):
                problem = (
                    "must be finite" if text.lower().lstrip("+-") in ("nan", "inf", "infinity") else "not a number"
                )
                raise InputError(path, f"line {lines[i]}, column {col}", f"{problem}: {row[c]!r}")
            value = float(text) * to_si
            if not abs(value) <= LIMITS[kind]:
                raise InputError(
                    path, f"line {lines[i]}, column {col}", f"implausible value {row[c]!r} (beyond {LIMITS[kind]:g} SI)"
                )
            out[i, j] = value
    return out


def approach_columns(
    path: Path,
    header: list[str],
    body: list[list[str]],
    n: int,
    to_si: float,
    prismatic: np.ndarray | None = None,
    to_m: float = 1.0,
) -> np.ndarray:
    """The optional ``before_q1..before_qn`` columns (N, n) in SI (``to_si`` for the joints'
    unit; ``to_m`` for the ``prismatic`` joints when they are in a length unit of their own):
    the joint values each row was approached from; NaN rows where the cells are empty (or the
    columns absent)."""
    before = np.full((len(body), n), np.nan)
    before_cols = [f"before_q{i}" for i in range(1, n + 1)]
    present = [c for c in header if c.startswith("before_q")]
    if not present:
        return before
    if present != before_cols:
        raise InputError(path, "header", f"the approach columns are {', '.join(before_cols)}: got {', '.join(present)}")
    given = np.array([[row[header.index(c)].strip() != "" for c in before_cols] for row in body])
    partial = np.flatnonzero(given.any(axis=1) & ~given.all(axis=1))
    if len(partial):
        where = f"line {line_numbers(body)[partial[0]]}"
        raise InputError(path, where, f"give all of before_q1..before_q{n} or none (the previous row)")
    rows = given.all(axis=1)
    if rows.any():
        # Rows without an approach parse as zeros, so that errors name the file's own lines.
        columns = [header.index(c) for c in before_cols]
        filled = Rows([row if full else [("0" if c in columns else v) for c, v in enumerate(row)]
                       for row, full in zip(body, rows, strict=True)], line_numbers(body))  # fmt: skip
        linear = np.zeros(n, bool) if prismatic is None else np.asarray(prismatic, bool)
        for j, column in enumerate(before_cols):
            kind, scale = ("length", to_m) if linear[j] else ("angle", to_si)
            before[rows, j] = parse_numbers(path, header, filled, [column], kind, scale)[rows, 0]
    return before


def speed_column(path: Path, header: list[str], body: list[list[str]]) -> np.ndarray:
    """The optional ``speed`` column (N,): each move's speed factor (1 without the column, or in
    an empty cell)."""
    speed = np.ones(len(body))
    named = [c for c in header if c.strip().lower() == "speed"]
    if len(named) > 1 or (named and named[0] != "speed"):
        raise InputError(path, "header", f"one column 'speed' (lower case) holds the speed factors, got {named}")
    if "speed" in header:
        column = header.index("speed")
        filled = Rows(
            [row if row[column].strip() else [*row[:column], "1", *row[column + 1 :]] for row in body],
            line_numbers(body),
        )
        speed = parse_numbers(path, header, filled, ["speed"], "unitless", 1.0)[:, 0]
        bad = np.flatnonzero(~((speed > 0) & (speed <= MAX_SPEED_FACTOR)))
        if len(bad):
            raise InputError(
                path, f"line {line_numbers(body)[bad[0]]}, column speed",
                f"a speed factor is in (0, {MAX_SPEED_FACTOR:g}] (1: the program's speed), got {speed[bad[0]]:g}",
            )  # fmt: skip
    return speed


def _history(
    path: Path, header: list[str], body: list[list[str]], q: np.ndarray, units: Units, order: str
) -> MotionHistory:
    """The configurations' motion history: ``before_q*`` where given, else the previous row
    (nothing with ``order: unknown``); ``speed`` factors (default 1)."""
    history = MotionHistory.in_order(q) if order == "measured" else MotionHistory.unknown(*q.shape)
    given = approach_columns(path, header, body, q.shape[1], units.to_rad)
    rows = np.all(np.isfinite(given), axis=1)
    before = history.before.copy()
    before[rows] = given[rows]
    return MotionHistory(before, speed_column(path, header, body))


def _table(path: Path, name: str, units: Units) -> Table:
    id_cols, value_cols, kinds = TABLES[name]
    header, body = read_csv(path, [*id_cols, *value_cols])
    kinds = (kinds,) * len(value_cols) if isinstance(kinds, str) else kinds
    values = np.empty((len(body), len(value_cols)))
    for j, (column, kind) in enumerate(zip(value_cols, kinds, strict=True)):
        to_si = units.to_m if kind == "length" else 1.0
        values[:, j] = parse_numbers(path, header, body, [column], kind, to_si)[:, 0]
    ids = {
        c: np.array(
            [check_name(row[header.index(c)].strip(), path, f"line {line}, column {c}")
             for line, row in numbered(body)],
            dtype=object,
        )
        for c in id_cols
    }  # fmt: skip
    _refuse_duplicates(path, name, ids, line_numbers(body))
    return Table(ids, values, line_numbers(body))


# The id columns that name one measurement (a point of the drawing is named by its point alone);
# a distance between a and b is the distance between b and a.
KEY_COLUMNS = {"points": ("point",)}
UNORDERED = ("point_distances", "tool_distances", "contacts", "tip_distances")


def _refuse_duplicates(path: Path, name: str, ids: dict[str, np.ndarray], lines: tuple[int, ...]) -> None:
    """A measurement given twice would count twice: refused, naming both lines."""
    columns = KEY_COLUMNS.get(name, tuple(ids))
    keys = zip(*(ids[c] for c in columns), strict=True)
    repeat = first_repeat(
        (line, tuple(sorted(key)) if name in UNORDERED else key) for line, key in zip(lines, keys, strict=True)
    )
    if repeat is not None:
        first, line, key = repeat
        raise InputError(
            path, f"lines {first} and {line}", f"{', '.join(columns)} {' '.join(map(repr, key))} given twice: "
            "each measurement once (repeated readings at one pose: give each its own configuration)",
        )  # fmt: skip


def _inside(root: Path, files: Fields, name: str) -> Path:
    """A table's path, which must stay inside the dataset directory."""
    relative = files.string(name)
    if "\x00" in relative:  # no file has it in its name, and pathlib refuses it with a ValueError
        raise files.error(name, f"a file name with a NUL character: {relative!r}")
    path = (root / relative).resolve()
    if not path.is_relative_to(root.resolve()):
        raise files.error(name, f"{relative!r} is outside the dataset directory {root}")
    return path


def load_dataset(path: str | Path) -> Dataset:
    """Load and validate a dataset directory (or its dataset.yaml); converts to SI."""
    path = Path(path)
    header_path = path / "dataset.yaml" if path.is_dir() else path
    root = header_path.parent
    raw = read_yaml(header_path)
    validate(raw, DatasetHeader, header_path)  # keys, types, nulls and choices; the checks below need the files
    doc = Fields(raw, header_path)
    units = parse_units(doc.raw("units", None), header_path)
    _, robot = referenced_robot(doc, root, inside=root)
    files = doc.sub("files")
    for kind in doc.items("measured"):  # each one of MEASUREMENTS: the schema
        if not files.has(kind):
            raise files.error(kind, f"'{kind}' is listed in measured but has no file")

    config_path = _inside(root, files, "configurations")
    joint_cols = [f"q{i}" for i in range(1, robot.n_joints + 1)]
    cfg_header, cfg_body = read_csv(config_path, ["config"])
    present = [c for c in cfg_header if c.startswith("q") and c[1:].isdigit()]
    if present != joint_cols:
        raise InputError(
            config_path,
            "header",
            f"{robot.name} has {robot.n_joints} joints: expected columns "
            f"{', '.join(joint_cols)}, got {', '.join(present) or 'none'}",
        )
    if not cfg_body:
        raise InputError(config_path, None, "no configurations")
    q = parse_numbers(config_path, cfg_header, cfg_body, joint_cols, "angle", units.to_rad)
    configs = np.array([row[cfg_header.index("config")].strip() for row in cfg_body], dtype=object)
    if len(set(configs)) != len(configs):
        raise InputError(config_path, "config", "duplicate configuration ids")
    history = _history(config_path, cfg_header, cfg_body, q, units, doc.string("order", "measured", ORDERS))

    noise = stated_noise(doc.raw("noise", {}), units, header_path)
    dataset = Dataset(root, robot, configs, q, header=dict(doc.data), noise=noise, history=history)
    known = set(configs)
    for name in TABLES:
        if not files.has(name):
            continue
        table_path = _inside(root, files, name)
        table = _table(table_path, name, units)
        for column in ("config", "config_a", "config_b"):
            unknown = [c for c in table.ids.get(column, []) if c not in known]
            if unknown:
                raise InputError(table_path, column, f"unknown configuration id {unknown[0]!r}")
        dataset.tables[name] = table
    if "camera_points" in dataset.tables or "pixels" in dataset.tables:
        if "points" not in dataset.tables:
            raise files.error("points", "camera measurements need the points table (object drawings)")
        point_names = set(dataset.tables["points"].ids["point"])
        for name in ("camera_points", "pixels"):
            if name in dataset.tables:
                bad = [p for p in dataset.tables[name].ids["point"] if p not in point_names]
                if bad:
                    raise InputError(_inside(root, files, name), "point", f"unknown point {bad[0]!r}")
    if "point_distances" in dataset.tables:
        _check_distances(dataset, _inside(root, files, "point_distances"))
    if "tracker_poses" in dataset.tables:
        _check_poses(dataset, _inside(root, files, "tracker_poses"))
    for name in ("distances", "tool_distances", "tip_distances"):
        if name in dataset.tables:
            bad = np.flatnonzero(~(dataset.tables[name].values[:, 0] > 0))
            if len(bad):
                raise InputError(
                    _inside(root, files, name), f"line {table_lines(dataset.tables[name])[bad[0]]}, column distance",
                    "a distance must be > 0",
                )
    if "tool_distances" in dataset.tables:
        table = dataset.tables["tool_distances"]
        same = np.flatnonzero(table.ids["config_a"] == table.ids["config_b"])
        if len(same):
            raise InputError(
                _inside(root, files, "tool_distances"), f"line {table_lines(table)[same[0]]}",
                "config_a and config_b are the same",
            )
    if doc.has("tracker") and "tracker_points" in dataset.tables:
        tracker = doc.sub("tracker")
        declared = {str(t) for t in tracker.items("targets")}
        dataset.target_tips = target_tips(tracker.sub("tips"), declared, dataset.robot) if tracker.has("tips") else {}
        bad = [t for t in dataset.tables["tracker_points"].ids["target"] if t not in declared]
        if bad:
            raise InputError(
                _inside(root, files, "tracker_points"),
                "target",
                f"target {bad[0]!r} is not in dataset.yaml tracker.targets ({', '.join(sorted(declared))})",
            )
    if doc.has("contact"):
        dataset.contact = _contact(doc.sub("contact"), units, dataset.robot)
    for name in ("contacts", "plane_contacts", "tip_distances"):
        if name in dataset.tables:
            _check_contacts(dataset, name, _inside(root, files, name), doc)
    if doc.has("self_observation"):
        _self_observation(dataset, doc.sub("self_observation"), units)
    if "observed_pixels" in dataset.tables:
        _check_observed(dataset, _inside(root, files, "observed_pixels"), doc)
    if doc.has("camera"):
        cam = doc.sub("camera")
        dataset.camera = parse_camera(cam)
        # The camera is the robot's tool: its mounting is the nominal T_n_C. Without one, the
        # camera may be fixed in the cell (static_camera) and the tool stays at the flange.
        dataset.camera_mounting = _pose(cam.sub("mounting"), units) if cam.has("mounting") else None
        dataset.robot = dataset.robot.with_tool(_pose(cam.sub("mounting", {}), units))
        if "pixels" in dataset.tables:
            table = dataset.tables["pixels"]
            _check_in_image(table, np.ones(len(table), dtype=bool), dataset.camera, _inside(root, files, "pixels"),
                            "dataset.yaml camera")  # fmt: skip
    if doc.has("tip"):
        dataset.tip = robot_tip(doc, "tip", dataset.robot)
    if doc.has("payload"):
        payload = doc.sub("payload")
        dataset.robot = dataset.robot.with_tool(
            dataset.robot.tool_pose,
            payload.number("mass", nonnegative=True),
            payload.vector("com", 3, [0, 0, 0], units.to_m),
        )
    if doc.has("fixture"):
        dataset.fixture_pose = _pose(doc.sub("fixture"), units)
    if doc.has("images"):
        dataset.images_dir = _inside(root, doc, "images")
        if not dataset.images_dir.is_dir():
            raise doc.error("images", f"no such directory: {dataset.images_dir}")
        dataset.boards = _boards(doc.sub("markers"), units)
    return dataset


def _check_distances(dataset: Dataset, path: Path) -> None:
    """Known distances join two different touched points, once each, and are positive."""
    if "touch_points" not in dataset.tables:
        raise InputError(path, None, "distances between touch points need the touch_points table")
    touched = set(dataset.tables["touch_points"].ids["point"])
    table = dataset.tables["point_distances"]
    for line, a, b, d in zip(
        table_lines(table), table.ids["point_a"], table.ids["point_b"], table.values[:, 0], strict=True
    ):
        for column, name in (("point_a", a), ("point_b", b)):
            if name not in touched:
                raise InputError(path, f"line {line}, column {column}", f"point {name!r} is never touched")
        if a == b:
            raise InputError(path, f"line {line}", f"a distance joins two different points, got {a!r} twice")
        if not d > 0:
            raise InputError(path, f"line {line}, column distance", f"must be > 0, got {d}")


def target_tips(tips: Fields, declared: set[str], robot: Robot) -> dict[str, str]:
    """``{target: tip}`` (a dataset's tracker.tips, an import mapping's target_tips): the
    named frame of a tree (Robot.tip_names) each target is fixed to, checked against the
    targets measured and the robot's tips; targets not listed are on the dataset's tip."""
    out = {}
    for target in tips.data:
        if str(target) not in declared:
            raise tips.error(str(target), f"not one of the tracker's targets ({', '.join(sorted(declared))})")
        out[str(target)] = robot_tip(tips, str(target), robot)
    return out


def robot_tip(fields: Fields, key: str, robot: Robot, default: str | None = None) -> str:
    """The tip of ``robot`` that ``fields[key]`` names ("flange": the robot's flange, by its name),
    or an error naming the field."""
    tip = fields.string(key) if default is None else fields.string(key, default)
    if robot.tip_error(tip):
        raise fields.error(key, robot.tip_error(tip))
    return robot.flange_name if tip == "flange" else tip


def _contact(section: Fields, units: Units, robot: Robot) -> ContactSetup:
    """dataset.yaml contact: elements on tips of the robot, planes with a nonzero normal (SI)."""
    elements = {}
    listed = section.sub("elements")
    for name in listed.data:
        element = listed.sub(str(name))
        elements[str(name)] = ContactElement(
            robot_tip(element, "tip", robot),
            element.vector("xyz", 3, scale=units.to_m),
            element.number("radius", scale=units.to_m, positive=True),
        )
    if not elements:
        raise section.error("elements", "no contact element")
    planes = {}
    if section.has("planes"):
        listed = section.sub("planes")
        for name in listed.data:
            plane = listed.sub(str(name))
            planes[str(name)] = (plane_normal(plane), plane.number("offset", scale=units.to_m))
    optional = {
        key: section.number(key, None, scale, positive=True) if section.has(key) else None
        for key, scale in (("position_sigma", units.to_m), ("radius_sigma", units.to_m),
                           ("plane_angle_sigma", units.to_rad), ("plane_offset_sigma", units.to_m))
    }  # fmt: skip
    return ContactSetup(
        elements,
        planes,
        optional["position_sigma"] or ContactSetup.position_sigma_m,
        optional["radius_sigma"] or ContactSetup.radius_sigma_m,
        optional["plane_angle_sigma"],
        optional["plane_offset_sigma"],
    )


def _check_contacts(dataset: Dataset, name: str, path: Path, doc: Fields) -> None:
    """Contacts name elements (and planes) of dataset.yaml contact; a ball never touches itself."""
    if dataset.contact is None:
        raise doc.error("contact", f"the {name} table needs the contact section (its elements and planes)")
    table = dataset.tables[name]
    columns = ("element",) if name == "plane_contacts" else ("element_a", "element_b")
    for column in columns:
        for line, element in zip(table_lines(table), table.ids[column], strict=True):
            if element not in dataset.contact.elements:
                known = ", ".join(sorted(dataset.contact.elements))
                raise InputError(path, f"line {line}, column {column}", f"element {element!r} is not in "
                                 f"dataset.yaml contact.elements ({known})")  # fmt: skip
    if name != "plane_contacts":
        for line, a, b in zip(table_lines(table), table.ids["element_a"], table.ids["element_b"], strict=True):
            if a == b:
                raise InputError(path, f"line {line}", f"joins two different elements, got {a!r} twice")
    else:
        for line, plane in zip(table_lines(table), table.ids["plane"], strict=True):
            if plane not in dataset.contact.planes:
                known = ", ".join(sorted(dataset.contact.planes)) or "none"
                raise InputError(path, f"line {line}, column plane", f"plane {plane!r} is not in "
                                 f"dataset.yaml contact.planes ({known})")  # fmt: skip


def _self_observation(dataset: Dataset, section: Fields, units: Units) -> None:
    """dataset.yaml self_observation: each camera's link becomes a tip of the dataset's robot (of
    the camera's name), each board's tip is one of the robot's."""
    robot = dataset.robot
    cameras, tips = section.sub("cameras"), list(robot.tips)
    for name in cameras.data:
        camera = cameras.sub(str(name))
        joint = camera.integer("joint", minimum=0)
        if joint > robot.n_links:
            raise camera.error("joint", f"{robot.name} has joints 1 to {robot.n_links} (0: the base)")
        if str(name) in robot.tip_names:
            raise cameras.error(str(name), f"a camera's name names its link's frame: {name!r} is a tip already")
        dataset.link_cameras[str(name)] = LinkCamera(joint - 1, _pose(camera.sub("mounting"), units),
                                                     parse_camera(camera))  # fmt: skip
        tips.append((str(name), joint - 1, np.eye(4)))
    if not dataset.link_cameras:
        raise section.error("cameras", "no camera")
    boards = section.sub("boards")
    for name in boards.data:
        board = boards.sub(str(name))
        tip = robot_tip(board, "tip", robot)
        corners = board.vector("corners", 2)
        if np.any(corners < 2) or np.any(corners != np.round(corners)):
            raise board.error("corners", f"expected two integers >= 2 (columns, rows), got {corners.tolist()}")
        points, names = board_corners(int(corners[0]), int(corners[1]),
                                      board.number("square", scale=units.to_m, positive=True))  # fmt: skip
        pose = _pose(board.sub("pose"), units)
        dataset.tip_boards[str(name)] = TipBoard(tip, pose, points, names)
    if not dataset.tip_boards:
        raise section.error("boards", "no board")
    dataset.robot = replace(robot, tips=tuple(tips))


def _check_observed(dataset: Dataset, path: Path, doc: Fields) -> None:
    """Observed pixels name the cameras, boards and points of self_observation."""
    if not dataset.link_cameras:
        raise doc.error("self_observation", "the observed_pixels table needs the self_observation section")
    table = dataset.tables["observed_pixels"]
    for line, camera, board, point in zip(
        table_lines(table), table.ids["camera"], table.ids["board"], table.ids["point"], strict=True
    ):
        if camera not in dataset.link_cameras:
            raise InputError(path, f"line {line}, column camera", f"camera {camera!r} is not in dataset.yaml "
                             f"self_observation.cameras ({', '.join(dataset.link_cameras)})")  # fmt: skip
        if board not in dataset.tip_boards:
            raise InputError(path, f"line {line}, column board", f"board {board!r} is not in dataset.yaml "
                             f"self_observation.boards ({', '.join(dataset.tip_boards)})")  # fmt: skip
        if point not in dataset.tip_boards[board].point_names:
            raise InputError(path, f"line {line}, column point", f"board {board!r} has no point {point!r} (its inner "
                             "corners are c<row><column>, c0000 to the last)")  # fmt: skip
    for camera, link_camera in dataset.link_cameras.items():
        _check_in_image(table, table.ids["camera"] == camera, link_camera.camera, path, f"camera {camera!r}")


def _check_in_image(table: Table, rows: np.ndarray, camera: Camera, path: Path, whose: str) -> None:
    """The pixels of ``rows`` lie in ``camera``'s image: -0.5 to width - 0.5 in u (pixel centres
    at integers, OpenCV's convention), alike in v; one outside is no measurement of this camera."""
    for column, j, size in (("u", 0, camera.width), ("v", 1, camera.height)):
        values = table.values[:, j]
        bad = np.flatnonzero(rows & ((values < -0.5) | (values > size - 0.5)))
        if len(bad):
            line = table_lines(table)[bad[0]]
            raise InputError(path, f"line {line}, column {column}", f"{column} = {values[bad[0]]:g} px is "
                             f"outside the image of {whose} ({camera.width} x {camera.height} px: -0.5 to "
                             f"{size - 0.5:g})")  # fmt: skip


# A plane's normal is a unit vector to this (its offset is along it: a normal of norm 2 would
# halve the offset meant, so none is normalised here); 1e-6 passes 8 printed digits.
NORMAL_TOLERANCE = 1e-6


def plane_normal(plane: Fields) -> np.ndarray:
    """A plane's ``normal``: a unit vector (within NORMAL_TOLERANCE, then normalised), refused
    otherwise with its norm (the plane ``n . x = offset`` would depend on the normal's length)."""
    normal = plane.vector("normal", 3)
    norm = float(np.linalg.norm(normal))
    if not norm > 1e-9:
        raise plane.error("normal", "a plane's normal must not be zero")
    if abs(norm - 1.0) > NORMAL_TOLERANCE:
        raise plane.error(
            "normal",
            f"a plane's normal must be a unit vector (its norm is {norm:.9g}): the offset is the distance along "
            "it, so a longer one would say another plane; divide both by the norm",
        )
    return normal / norm


def _check_poses(dataset: Dataset, path: Path) -> None:
    """Unit quaternions (normalised here)."""
    table = dataset.tables["tracker_poses"]
    norms = np.linalg.norm(table.values[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
    if len(bad):
        raise InputError(
            path, f"line {table_lines(table)[bad[0]]}, columns qw-qz",
            f"not a unit quaternion (norm {norms[bad[0]]:.6g})",
        )
    table.values[:, 3:] /= norms[:, None]  # one pose per configuration: _refuse_duplicates


def _boards(markers: Fields, units: Units) -> list:
    # markers.dictionary: DICT_5X5_1000 only (the schema's Markers)
    boards = []
    for board in markers.sub_list("boards"):
        squares = board.vector("squares", 2)
        corners = [str(c) for c in board.items("corners")]
        if len(corners) != int(squares[0] - 1) * int(squares[1] - 1):
            raise board.error("corners", f"expected {(squares[0] - 1) * (squares[1] - 1):.0f} corner names")
        boards.append(
            SideBoard(
                board.string("name"),
                (int(squares[0]), int(squares[1])),
                board.number("square", scale=units.to_m, positive=True),
                board.integer("first_id", minimum=0),
                _pose(board.sub("pose"), units),
                tuple(corners),
            )
        )
    return boards


def _pose(fields: Fields, units: Units) -> np.ndarray:
    return pose_from_xyz_rpy(
        fields.vector("xyz", 3, [0, 0, 0], units.to_m), fields.vector("rpy", 3, [0, 0, 0], units.to_rad)
    )


def write_header(path: Path, header: dict) -> None:
    write_text(Path(path) / "dataset.yaml", yaml.safe_dump(header, sort_keys=False))
