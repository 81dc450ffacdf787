"""The calibration problem: configurations split into fitting and validation sets, the
candidate parameters, and the measurements of the chosen formulation.

Pair selection (the seed's relative formulation): the fitting images are split into
groups of ``pairs.group_images`` images by a seeded random draw; each next image of a group
is drawn, where possible, from the category the config asks for relative to the previous
one (default: another object, which the seed found essential). A group's factor carries
every point pair among its observations through orthonormal contrasts (see
fgcal.factors.PointPairFactor), so each observation belongs to exactly one factor and the
factors' noise is independent and exact. With four points per image and G images, a group
keeps 4G - 1 of its 4G coordinates' worth of information; the lost one is the unobservable
common position.
"""

from __future__ import annotations

import copy
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ..camera import solve_pnp
from ..dataset import Dataset, Table
from ..errors import InputError
from ..parameters import default_compliant_joints, split_name
from ..robot import Robot
from ..se3 import pose, quaternion_rotation
from .config import CalibrationConfig

CATEGORIES = ("same_image", "same_side", "same_object", "other_object")


@dataclass
class PairGroup:
    """Observations of a group of images: fitting-set index of each image, and per
    observation the image it belongs to, the camera-frame point and the drawing point."""

    images: list[int]
    owner: np.ndarray  # observation -> position in images
    c: np.ndarray
    p_F: np.ndarray
    labels: list[tuple[str, str]]  # (object, side) of each image
    names: list[str] = field(default_factory=list)  # point name of each observation


@dataclass
class Problem:
    config: CalibrationConfig
    dataset: Dataset
    robot: Robot
    frame: str
    fit: np.ndarray  # indices into dataset configurations
    test: np.ndarray
    candidates: list[str]
    pairs: list[PairGroup] = field(default_factory=list)
    fixture_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    tracker_obs: list[tuple[int, int, np.ndarray]] = field(default_factory=list)  # (fit index, target, m)
    pixel_obs: list[tuple[int, np.ndarray, np.ndarray, str]] = field(
        default_factory=list
    )  # (fit index, p_F, px, point)
    targets: list[str] = field(default_factory=list)
    touch_obs: list[tuple[int, int]] = field(default_factory=list)  # (fit index, touch point index)
    touch_points: list[str] = field(default_factory=list)  # names of the fixed points (sockets)
    spacings: list[tuple[int, int, float]] = field(default_factory=list)  # (point, point, distance m)
    pose_obs: list[tuple[int, np.ndarray]] = field(default_factory=list)  # (fit index, measured 4x4 pose)
    # (fit index, pivot or -1, distance m, other configuration's fit index or -1)
    distance_obs: list[tuple[int, int, float, int]] = field(default_factory=list)
    pivots: list[str] = field(default_factory=list)  # names of a ballbar's fixed pivots
    skipped_images: list[tuple[str, str]] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)  # outliers removed: config, kind, point or target, size
    detection: dict = field(default_factory=dict)

    @property
    def q_fit(self) -> np.ndarray:
        return self.dataset.q[self.fit]

    @property
    def n_residuals(self) -> int:
        if self.config.formulation == "pairs":
            return sum(3 * (len(p.c) - 1) for p in self.pairs)
        if self.config.formulation in ("projection", "static_camera"):
            return 2 * len(self.pixel_obs)
        if self.config.formulation == "poses":
            return 6 * len(self.pose_obs)
        if self.config.formulation == "distances":
            return len(self.distance_obs)
        if self.config.formulation == "touch":
            return 3 * len(self.touch_obs) + len(self.spacings)
        return 3 * len(self.tracker_obs)

    def pair_categories(self) -> dict[str, int]:
        """Point pairs of each category carried by the factors (every pair within a group)."""
        counts: Counter = Counter()
        for group in self.pairs:
            sizes = Counter(group.owner.tolist())
            for a in sizes:
                counts["same_image"] += sizes[a] * (sizes[a] - 1) // 2
                for b in sizes:
                    if a < b:
                        counts[category(group.labels[a], group.labels[b])] += sizes[a] * sizes[b]
        return {c: counts.get(c, 0) for c in CATEGORIES}


def category(a: tuple[str, str], b: tuple[str, str]) -> str:
    """Pair category of two images from their (object, side)."""
    if a[0] != b[0]:
        return "other_object"
    return "same_side" if a[1] == b[1] else "same_object"


def fitting_rows(problem: Problem, table: Table, key: str, subset: np.ndarray | None = None):
    """(index in the subset, id in column ``key``, values) of each row of ``table`` that belongs
    to a configuration of ``subset`` (default the fitting set); other rows are left out."""
    config_pos = {c: i for i, c in enumerate(problem.dataset.configs)}
    fit_pos = {int(c): i for i, c in enumerate(problem.fit if subset is None else subset)}
    for cid, name, values in zip(table.ids["config"], table.ids[key], table.values, strict=True):
        index = fit_pos.get(config_pos[cid])
        if index is not None:
            yield index, name, values


def compliant_joints(robot: Robot, config: CalibrationConfig) -> tuple[int, ...]:
    """The config's compliant joints, or by default the seed's 1-3 that the robot has."""
    if config.compliant_joints is None:
        return default_compliant_joints(robot.n_joints)
    return config.compliant_joints


def candidate_parameters(robot: Robot, config: CalibrationConfig) -> list[str]:
    """Parameters the model could estimate: the model's kinds, compliances of the compliant
    joints, base and tool. Identifiability analysis decides which the data determine."""
    kinds = {"theta", "d", "a", "alpha", "tx", "ty", "tz", "rx", "ry", "rz"}
    if config.model in ("DH,s", "DH,s,e"):
        kinds |= {"sx", "sy"}
    names = []
    for name in robot.parameter_names:
        kind, owner = split_name(name)
        if (
            isinstance(owner, str)
            or kind in kinds
            or (config.model == "DH,s,e" and kind in ("kx", "ky", "kz") and owner in compliant_joints(robot, config))
        ):
            names.append(name)
    return names


def split(n: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split of n configurations into fitting and held-out indices."""
    order = np.random.default_rng(seed).permutation(n)
    n_test = round(holdout * n)
    return np.sort(order[n_test:]), np.sort(order[:n_test])


def build_problem(dataset: Dataset, config: CalibrationConfig, progress=None) -> Problem:
    robot = dataset.robot.with_model(config.model)
    for j in compliant_joints(robot, config):
        if j > robot.n_joints:
            raise InputError(config.path, "compliant_joints", f"joint {j} does not exist on {robot.name}")
    detections = None
    if config.pixels_from == "images":
        from ..markers import detect_images

        detections = detect_images(dataset, progress=progress)
        dataset = copy.copy(dataset)
        dataset.tables = {**dataset.tables, "pixels": detections.pixels}
    fit, test = split(len(dataset.configs), config.holdout, config.split_seed)
    if config.validation_dataset is not None:
        from .validation_set import with_validation_set

        dataset, validation = with_validation_set(dataset, config)
        test = np.concatenate([test, validation])
    problem = Problem(config, dataset, robot, config.frame, fit, test, candidate_parameters(robot, config))
    if detections is not None:
        problem.skipped_images = detections.skipped
        problem.detection = {
            "images": len(dataset.configs),
            "skipped": len(detections.skipped),
            "corners": detections.corners,
            "rejected_by_gate": detections.rejected,
        }
    if config.formulation == "pairs":
        _build_pairs(problem)
    elif config.formulation in ("projection", "static_camera"):
        _build_projection(problem)
    elif config.formulation == "poses":
        _build_poses(problem)
    elif config.formulation == "distances":
        _build_distances(problem)
    elif config.formulation == "touch":
        _build_touch(problem)
    else:
        _build_tracker(problem)
    return problem


def _require_pixels(dataset: Dataset, who: str) -> None:
    if "pixels" not in dataset.tables or dataset.camera is None:
        raise InputError(
            dataset.path / "dataset.yaml", "measured", f"{who} the pixels table and the camera intrinsics (camera:)"
        )


def camera_points_from_pixels(dataset: Dataset) -> Table:
    """3D points in the camera frame from detections: OpenCV solvePnP (IPPE) on each image's
    points with their drawing coordinates, then ``c = T_C_F p_F``, as the seed does. Images
    with fewer than four points are skipped."""
    _require_pixels(dataset, "pairs from pixels need")
    points = dataset.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    table = dataset.tables["pixels"]
    images: dict[str, list[int]] = {}
    for row, cid in enumerate(table.ids["config"]):
        images.setdefault(str(cid), []).append(row)
    configs, names, values = [], [], []
    for cid, rows in images.items():
        if len(rows) < 4:
            continue
        p_F = points.values[[where[table.ids["point"][r]] for r in rows]]
        T_C_F = solve_pnp(p_F, table.values[rows], dataset.camera)
        if T_C_F is None:
            continue
        values.append(p_F @ T_C_F[:3, :3].T + T_C_F[:3, 3])
        configs += [cid] * len(rows)
        names += [table.ids["point"][r] for r in rows]
    return Table(
        {"config": np.array(configs, dtype=object), "point": np.array(names, dtype=object)},
        np.vstack(values) if values else np.zeros((0, 3)),
    )


def _build_pairs(problem: Problem) -> None:
    data, config = problem.dataset, problem.config
    if config.pair_points_from == "pixels":
        # The dataset itself is left as loaded; the problem works on its own copy of the tables.
        data = problem.dataset = copy.copy(data)
        data.tables = {**data.tables, "camera_points": camera_points_from_pixels(data)}
    if "camera_points" not in data.tables:
        raise InputError(
            data.path / "dataset.yaml",
            "measured",
            "the pair formulation needs camera_points (3D points in the camera frame)",
        )
    if data.fixture_pose is not None:
        problem.fixture_rotation = data.fixture_pose[:3, :3]
    problem.pairs = pair_groups(problem, problem.fit)
    if len({j for g in problem.pairs for j in g.images}) < 2:
        raise InputError(
            data.path / "camera_points.csv",
            None,
            "fewer than 2 fitting images with points: the pair formulation needs several",
        )


def pair_groups(problem: Problem, subset: np.ndarray, exclude: set[tuple[str, str]] = frozenset()) -> list[PairGroup]:
    """The point-pair groups of the images of ``subset`` (configuration indices), as the
    module docstring describes; image indices are positions in ``subset``. Observations
    (config id, point) in ``exclude`` (rejected gross errors) are left out."""
    data, config = problem.dataset, problem.config
    points = data.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    table = data.tables["camera_points"]
    images: dict[int, list[tuple[int, np.ndarray]]] = {}
    chosen = problem.fit if subset is None else subset
    for index, point, xyz in fitting_rows(problem, table, "point", subset):
        if (str(data.configs[chosen[index]]), str(point)) not in exclude:
            images.setdefault(index, []).append((where[point], xyz))
    groups: list[PairGroup] = []

    def label(j: int) -> tuple[str, str]:
        first = images[j][0][0]
        return str(points.ids["object"][first]), str(points.ids["side"][first])

    preference = {
        "other_object": ("other_object", "same_object", "same_side"),
        "same_object": ("same_object", "other_object", "same_side"),
        "same_side": ("same_side", "same_object", "other_object"),
        "any": (),
    }[config.pair_partner]
    rng = np.random.default_rng(config.pair_seed)
    remaining = [int(j) for j in rng.permutation(sorted(images))]
    size = config.group_images
    while remaining:
        group = [remaining.pop(0)]
        while len(group) < size and remaining:
            previous = label(group[-1])
            choice = None
            for wanted in preference:
                options = [k for k in remaining if category(previous, label(k)) == wanted]
                if options:
                    choice = options[int(rng.integers(len(options)))]
                    break
            if choice is None:
                choice = remaining[int(rng.integers(len(remaining)))]
            remaining.remove(choice)
            group.append(choice)
        observations = [(i, point, xyz) for i, j in enumerate(group) for point, xyz in images[j]]
        if len(observations) < 2:
            continue
        groups.append(
            PairGroup(
                images=group,
                owner=np.array([o[0] for o in observations]),
                c=np.array([o[2] for o in observations]),
                p_F=points.values[[o[1] for o in observations]],
                labels=[label(j) for j in group],
                names=[str(points.ids["point"][o[1]]) for o in observations],
            )
        )
    return groups


def _build_projection(problem: Problem) -> None:
    data = problem.dataset
    _require_pixels(data, f"the {problem.config.formulation} formulation needs")
    points = data.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    table = data.tables["pixels"]
    for index, point, uv in fitting_rows(problem, table, "point"):
        problem.pixel_obs.append((index, points.values[where[point]], uv, str(point)))
    if len({o[0] for o in problem.pixel_obs}) < 3:
        raise InputError(data.path / "pixels.csv", None, "too few fitting images with pixels")


def _build_tracker(problem: Problem) -> None:
    data = problem.dataset
    table = _measured(problem, "tracker_points")
    # The targets the fit sees; one measured only at held-out configurations (a test point of a
    # validation set) is scored through its declared or leave-one-out position.
    problem.targets = sorted({target for _, target, _ in fitting_rows(problem, table, "target")})
    target_index = {t: i for i, t in enumerate(problem.targets)}
    for index, target, xyz in fitting_rows(problem, table, "target"):
        problem.tracker_obs.append((index, target_index[target], xyz))
    if len(problem.tracker_obs) < 3 * len(problem.targets) + 2:
        raise InputError(
            data.path / "tracker_points.csv",
            None,
            f"only {len(problem.tracker_obs)} tracker measurements in the fitting set: too few",
        )


def _build_touch(problem: Problem) -> None:
    data = problem.dataset
    table = _measured(problem, "touch_points")
    problem.touch_points = sorted(set(table.ids["point"]))
    index = {name: i for i, name in enumerate(problem.touch_points)}
    for fit_index, point, _ in fitting_rows(problem, table, "point"):
        problem.touch_obs.append((fit_index, index[point]))
    # A point touched once only locates itself: it says nothing about the robot.
    lonely = _fewest(problem.touch_points, [k for _, k in problem.touch_obs], 2)
    if lonely is not None:
        raise InputError(
            data.path / "touch_points.csv",
            "point",
            f"point {lonely[0]!r} is touched {lonely[1]} times in the fitting set: "
            "each point needs several touches in different configurations",
        )
    distances = data.tables.get("point_distances")
    if distances is not None:
        for a, b, d in zip(distances.ids["point_a"], distances.ids["point_b"], distances.values[:, 0], strict=True):
            problem.spacings.append((index[a], index[b], float(d)))


def _build_poses(problem: Problem) -> None:
    data = problem.dataset
    for index, _, values in fitting_rows(problem, _measured(problem, "tracker_poses"), "config"):
        problem.pose_obs.append((index, pose(quaternion_rotation(values[3:]), values[:3])))
    if len(problem.pose_obs) < 3:
        raise InputError(
            data.path / "tracker_poses.csv", None, f"only {len(problem.pose_obs)} poses in the fitting set: too few"
        )


def _build_distances(problem: Problem) -> None:
    """Readings to pivots (``distances``) and between two configurations (``tool_distances``);
    a reading between configurations fits when both are in the fitting set."""
    data = problem.dataset
    if "distances" not in data.tables and "tool_distances" not in data.tables:
        raise InputError(
            data.path / "dataset.yaml", "measured", "the distances formulation needs distances or tool_distances"
        )
    if "distances" in data.tables:
        table = data.tables["distances"]
        problem.pivots = sorted(set(table.ids["pivot"]))
        index = {name: i for i, name in enumerate(problem.pivots)}
        for fit_index, pivot, values in fitting_rows(problem, table, "pivot"):
            problem.distance_obs.append((fit_index, index[pivot], float(values[0]), -1))
        # Three for the pivot, three for the ball, and more for the robot.
        few = _fewest(problem.pivots, [o[1] for o in problem.distance_obs], 6)
        if few is not None:
            raise InputError(
                data.path / "distances.csv",
                "pivot",
                f"pivot {few[0]!r} has {few[1]} readings in the fitting set: each pivot needs "
                "many, in clearly different configurations",
            )
    if "tool_distances" in data.tables:
        for a, b, d in between_configurations(problem, data.tables["tool_distances"], problem.fit):
            problem.distance_obs.append((a, -1, d, b))
    if len(problem.distance_obs) < 6:
        raise InputError(
            data.path / "dataset.yaml",
            "measured",
            f"only {len(problem.distance_obs)} distances in the fitting set: too few to calibrate",
        )


def between_configurations(problem: Problem, table: Table, subset: np.ndarray, within: np.ndarray | None = None):
    """(index of a, index of b, distance) of each reading between configurations a and b (rows
    of ``table``) that involves ``subset``; indices into ``subset`` followed by ``within``
    (default nothing more: both ends in the subset)."""
    config_pos = {c: i for i, c in enumerate(problem.dataset.configs)}
    order = [int(c) for c in subset] + ([int(c) for c in within] if within is not None else [])
    position = {c: i for i, c in enumerate(order)}
    n_subset = len(subset)
    for a, b, values in zip(table.ids["config_a"], table.ids["config_b"], table.values, strict=True):
        ia, ib = position.get(config_pos[a]), position.get(config_pos[b])
        if ia is not None and ib is not None and (ia < n_subset or ib < n_subset):
            yield ia, ib, float(values[0])


def _measured(problem: Problem, table: str) -> Table:
    """The dataset's table that the formulation needs, or an error naming it."""
    data = problem.dataset
    if table not in data.tables:
        raise InputError(
            data.path / "dataset.yaml", "measured", f"the {problem.config.formulation} formulation needs {table}"
        )
    return data.tables[table]


def _fewest(names: list[str], indices: list[int], minimum: int) -> tuple[str, int] | None:
    """The first of ``names`` that ``indices`` (observations' name indices) count fewer than
    ``minimum`` times, with its count; None when every name has enough."""
    counts = Counter(indices)
    for k, name in enumerate(names):
        if counts.get(k, 0) < minimum:
            return name, counts.get(k, 0)
    return None
