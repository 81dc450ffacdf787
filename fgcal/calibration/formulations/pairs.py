"""The seed's relative point-pair formulation (SPEC section 4, eq. 3): a camera on the flange
measures points of the calibration objects in its own frame, and pairs of such points, seen
from different configurations, close the chain without measuring the base
(fgcal.factors.PointPairs). Unknowns besides P: none, or the fixture's orientation R_W_F when
the config estimates it.

Pair selection: the fitting images are split into groups of ``pairs.group_images`` images by
a seeded random draw; each next image of a group is drawn, where possible, from the category
the config asks for relative to the previous one (default: another object, which the seed
found essential). A group's factor rows carry every point pair among its observations through
orthonormal contrasts, so each observation belongs to exactly one group and the rows' noise is
independent and exact. With four points per image and G images, a group keeps 4G - 1 of its
4G coordinates' worth of information; the lost one is the unobservable common position.

Scored against held-out images by the point pairs of the held-out images, grouped as the
fitting ones (no gauge: a pair does not depend on where the robot stands); against the truth
by a point where the camera works, in W, the common offset removed (with an estimated fixture
orientation, the best rigid motion).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset, Table
from ...data.truth import Truth
from ...factors import MeasurementSet, PointPairs, RobustLoss
from ...model.camera import solve_pnp
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..goodness import chi_median
from ..plan_model import FlangeCamera, Planning
from ..problem import Formulation, Keys, Observations, Problem, Rejection, Scored, measured_table, rows_of, subset_of
from ..settings import MeasurementSettings
from ..state import Auxiliary, State
from .common import require_pixels
from .projection import camera_work_point

CATEGORIES = ("same_image", "same_side", "same_object", "other_object")
PREFERENCE = {
    "other_object": ("other_object", "same_object", "same_side"),
    "same_object": ("same_object", "other_object", "same_side"),
    "same_side": ("same_side", "same_object", "other_object"),
    "any": (),
}


@dataclass(frozen=True)
class PairGroup:
    """Observations of a group of images: per image its configuration (index into the
    observations' config_ids), and per observation the image it belongs to, the camera-frame
    point and the drawing point."""

    images: list[int]
    owner: np.ndarray  # observation -> position in images
    c: np.ndarray
    p_F: np.ndarray
    labels: list[tuple[str, str]]  # (object, side) of each image
    names: list[str] = field(default_factory=list)  # point name of each observation

    @property
    def configs(self) -> np.ndarray:
        """Configuration of each observation."""
        return np.array(self.images)[self.owner]


@dataclass(frozen=True)
class PairObservations(Observations):
    groups: tuple[PairGroup, ...]

    @property
    def n_residuals(self) -> int:
        return sum(3 * (len(g.c) - 1) for g in self.groups)

    def categories(self) -> dict[str, int]:
        """Point pairs of each category carried by the groups (every pair within a group)."""
        counts: Counter = Counter()
        for group in self.groups:
            sizes = Counter(group.owner.tolist())
            for a in sizes:
                counts["same_image"] += sizes[a] * (sizes[a] - 1) // 2
                for b in sizes:
                    if a < b:
                        counts[category(group.labels[a], group.labels[b])] += sizes[a] * sizes[b]
        return {c: counts.get(c, 0) for c in CATEGORIES}


class Pairs(Formulation):
    name = "pairs"
    frame = "tool"
    kind = "camera_points"
    settings_read = ("pairs", "pairs.groups", "fixture_orientation", "noise.camera_point_sigma", "pixels_from")
    score = "point_pair"
    score_vectors = False
    likely_causes = (
        "camera points in another unit or frame, point names that do not match the drawing, a wrong camera mounting "
        "or fixture pose, or joint angles in other units than units: declares"
    )
    instrument = "camera"
    not_incremental = (
        "its measurements are relative motions between the images of a group (several configurations at once), "
        "not one configuration's observations; refine a flange camera online with the projection formulation"
    )

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.camera_point_m

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid" if settings.fixture_orientation == "estimate" else "translation"

    def planning(self, settings: MeasurementSettings) -> Planning:
        rotation = settings.fixture_orientation == "estimate"
        return FlangeCamera(rotation=rotation, group_images=settings.pairs.group_images)

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        observations = pair_observations(dataset, settings, fit)
        if len({j for g in observations.groups for j in g.images}) < 2:
            raise InputError(
                dataset.path / "camera_points.csv",
                None,
                "fewer than 2 fitting images with points: the pair formulation needs several",
            )
        return observations

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        """The held-out images' pairs, without the camera points that the gross-error test of
        :meth:`reject` flags with the final model (named, ``held_out``)."""
        excluded = {(r.config, r.name) for r in problem.rejected if r.kind == self.kind}
        observations = pair_observations(problem.dataset, problem.settings, problem.test, excluded)
        if not observations.groups:
            return None, []
        kinematics = problem.kinematics(state, [], observations)
        deviations, threshold = _deviations(
            observations.groups, kinematics.poses(None), _rotation(problem, state), self.sigma(problem.settings)
        )
        every = np.concatenate(deviations)
        flagged = []
        if (every > threshold).sum() <= MAX_FLAGGED_FRACTION * len(every):
            sigma = self.sigma(problem.settings)
            for group, deviation in zip(observations.groups, deviations, strict=True):
                for o in np.flatnonzero(deviation > threshold):
                    config = str(observations.config_ids[group.images[group.owner[o]]])
                    flagged.append(self.rejection(config, group.names[o], deviation[o], deviation[o] * sigma, True))
        if flagged:
            excluded |= {(r.config, r.name) for r in flagged}
            observations = pair_observations(problem.dataset, problem.settings, problem.test, excluded)
        return (observations if observations.groups else None), flagged

    def initial_state(self, problem: Problem) -> State:
        aux = {}
        if problem.settings.fixture_orientation == "estimate":
            aux["fixture_rotation"] = Auxiliary("rot3", fixture_rotation(problem.dataset))
        return State(problem.robot.parameter_vector(), aux)

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        groups = [(g.configs, g.c, g.p_F) for g in observations.groups]
        estimated = "fixture_rotation" in keys
        return [
            PointPairs(
                kinematics,
                keys.params,
                groups,
                problem.settings.noise.camera_point_m,
                fixture_key=keys["fixture_rotation"] if estimated else None,
                fixture_rotation=_rotation(problem, state),
                robust=robust,
            )
        ]

    def score_configs(self, main: MeasurementSet) -> np.ndarray:
        # Contrast r of a group sets its observation r + 1 against the ones before it.
        sizes = np.diff(np.append(main.unit_starts, main.n_rows)) // 3 + 1
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        return np.concatenate([main.configs[a + 1 : a + n] for a, n in zip(starts, sizes, strict=True)])

    def reject(
        self, problem: Problem, sets: list[MeasurementSet], values, scale: float
    ) -> tuple[Observations, list[Rejection]] | None:
        """Camera points (always, whatever the robust loss): in a group every observation's
        ``X c - R_W_F p`` is the same point (the unknown base offset) plus noise, so an
        observation farther than REJECT_SIGMA robust sigmas from its group's median is a gross
        error. (The pair contrasts mix a group's observations and cannot name one.)"""
        main = sets[0]
        inputs = main.read(values)
        params = inputs[0] if main.params_key is not None else None
        rotation = inputs[-1].matrix() if main.estimate_fixture else main.fixture_rotation
        sigma = self.sigma(problem.settings)
        observations = problem.observations
        deviations, threshold = _deviations(observations.groups, main.kinematics.poses(params), rotation, sigma)
        every = np.concatenate(deviations)
        if not (every > threshold).any() or (every > threshold).sum() > MAX_FLAGGED_FRACTION * len(every):
            return None
        kept_groups, records = [], []
        for group, deviation in zip(observations.groups, deviations, strict=True):
            bad = deviation > threshold
            for o in np.flatnonzero(bad):
                config = str(observations.config_ids[group.images[group.owner[o]]])
                records.append(self.rejection(config, group.names[o], deviation[o], deviation[o] * sigma))
            keep = ~bad
            if keep.sum() >= 2:
                used = sorted(set(group.owner[keep].tolist()))
                renumber = {old: new for new, old in enumerate(used)}
                kept_groups.append(
                    PairGroup(
                        images=[group.images[i] for i in used],
                        owner=np.array([renumber[i] for i in group.owner[keep]]),
                        c=group.c[keep],
                        p_F=group.p_F[keep],
                        labels=[group.labels[i] for i in used],
                        names=[n for n, k in zip(group.names, keep, strict=True) if k],
                    )
                )
        return PairObservations(observations.config_ids, observations.q, tuple(kept_groups)), records

    def scored(self, problem: Problem, state: State) -> Scored:
        return Scored(camera_work_point(problem.dataset)[None, :], extra={"camera_origin": np.zeros(3)})

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        # The true tool.* perturbs the simulation's nominal mounting, which a dataset's (or a
        # user's) mounting guess need not equal.
        robot = problem.dataset.robot.with_model(truth.model).with_tool(truth.camera_mounting_nominal)
        return robot, State(robot.parameter_vector(truth.parameters))

    def details(self, problem: Problem) -> dict:
        return {"pair_categories": problem.observations.categories()}


MAX_FLAGGED_FRACTION = 0.1
REJECT_SIGMA = 5.0


def fixture_rotation(dataset: Dataset) -> np.ndarray:
    """R_W_F of the dataset's fixture drawing (identity without one)."""
    return dataset.fixture_pose[:3, :3].copy() if dataset.fixture_pose is not None else np.eye(3)


def _rotation(problem: Problem, state: State) -> np.ndarray:
    estimated = state.get("fixture_rotation")
    return estimated if estimated is not None else fixture_rotation(problem.dataset)


def _deviations(
    groups: tuple[PairGroup, ...], poses: np.ndarray, rotation: np.ndarray, sigma: float
) -> tuple[list[np.ndarray], float]:
    """Per group, each observation's distance (in sigmas) from its group's median of
    ``X c - R_W_F p``, and the rejection threshold (REJECT_SIGMA robust sigmas of a 3-D point)."""
    deviations = []
    for group in groups:
        T = poses[group.configs]
        world = np.einsum("oij,oj->oi", T[:, :3, :3], group.c) + T[:, :3, 3] - group.p_F @ rotation.T
        deviations.append(np.linalg.norm(world - np.median(world, axis=0), axis=1) / sigma)
    every = np.concatenate(deviations) if deviations else np.zeros(0)
    median_3d = float(chi_median(np.array([3]))[0])
    scale = max(1.0, float(np.median(every)) / median_3d) if every.size else 1.0
    return deviations, REJECT_SIGMA * median_3d * scale


def category(a: tuple[str, str], b: tuple[str, str]) -> str:
    """Pair category of two images from their (object, side)."""
    if a[0] != b[0]:
        return "other_object"
    return "same_side" if a[1] == b[1] else "same_object"


def camera_points_table(dataset: Dataset, settings: MeasurementSettings) -> Table:
    """The camera points the pairs are made of: the dataset's, or from its pixels."""
    if settings.pairs.points_from == "pixels":
        return camera_points_from_pixels(dataset)
    if "camera_points" not in dataset.tables:
        raise InputError(
            dataset.path / "dataset.yaml",
            "measured",
            "the pair formulation needs camera_points (3D points in the camera frame)",
        )
    return dataset.tables["camera_points"]


def camera_points_from_pixels(dataset: Dataset) -> Table:
    """3D points in the camera frame from detections: OpenCV solvePnP (IPPE) on each image's
    points with their drawing coordinates, then ``c = T_C_F p_F``, as the seed does. Images
    with fewer than four points are skipped."""
    require_pixels(dataset, "pairs from pixels need")
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


class _Remaining:
    """Which of n positions remain, as a Fenwick tree: counts and removals in O(log n)."""

    def __init__(self, n: int, positions) -> None:
        self.tree = [0] * (n + 1)
        self.total = 0
        for position in positions:
            self.add(position, 1)

    def add(self, position: int, delta: int) -> None:
        self.total += delta
        i = position + 1
        while i < len(self.tree):
            self.tree[i] += delta
            i += i & -i


def _kth(parts: list[tuple[_Remaining, int]], k: int) -> int:
    """The position of the k-th (0-based) remaining one of a signed sum of trees."""
    n = len(parts[0][0].tree) - 1
    position, step = 0, 1 << n.bit_length()
    while step:
        ahead = position + step
        if ahead <= n:
            count = sum(sign * tree.tree[ahead] for tree, sign in parts)
            if count <= k:
                position, k = ahead, k - count
        step >>= 1
    return position


def _grouped(order: list[int], labels: list[tuple[str, str]], settings: MeasurementSettings, rng) -> list[list[int]]:
    """Images in groups of settings.pairs.group_images: each group starts with the first image
    left in ``order``, and each next image is drawn (``rng``) among those left in the preferred
    category of pair with the previous one (PREFERENCE), else among all left. Counting trees per
    (object, side), per object and in all make each draw O(log n): the groups are those of
    scanning what is left for every draw, in linear time instead of quadratic."""
    preference, size = PREFERENCE[settings.pairs.partner], settings.pairs.group_images
    n = len(order)
    everything = _Remaining(n, range(n))
    by_object = {obj: _Remaining(n, [p for p in range(n) if labels[p][0] == obj]) for obj, _ in set(labels)}
    by_side = {lab: _Remaining(n, [p for p in range(n) if labels[p] == lab]) for lab in set(labels)}

    def take(position: int) -> int:
        for tree in (everything, by_object[labels[position][0]], by_side[labels[position]]):
            tree.add(position, -1)
        return position

    groups = []
    while everything.total:
        position = take(_kth([(everything, 1)], 0))
        group = [position]
        while len(group) < size and everything.total:
            previous = labels[group[-1]]
            choice = None
            for wanted in preference:
                parts = {
                    "same_side": [(by_side[previous], 1)],
                    "same_object": [(by_object[previous[0]], 1), (by_side[previous], -1)],
                    "other_object": [(everything, 1), (by_object[previous[0]], -1)],
                }[wanted]
                count = sum(sign * tree.total for tree, sign in parts)
                if count:
                    choice = _kth(parts, int(rng.integers(count)))
                    break
            if choice is None:
                choice = _kth([(everything, 1)], int(rng.integers(everything.total)))
            group.append(take(choice))
        groups.append([order[p] for p in group])
    return groups


def _prescribed(dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, images: dict) -> list[list[int]]:
    """The groups ``pairs.groups`` prescribes among the ``images`` (positions in ``subset``):
    each group its file's images of the subset, in the file's order, the groups in the order of
    their first line; none without the setting. A configuration the dataset does not have is an
    error (a plan's file for another dataset)."""
    rows = settings.pairs.groups
    if rows is None:
        return []
    known = {str(c) for c in dataset.configs}
    lines = settings.pairs.groups_lines or tuple(range(2, len(rows) + 2))
    for line, (cid, _) in zip(lines, rows, strict=True):
        if cid not in known:
            raise InputError(settings.pairs.groups_file, f"line {line}, column config",
                             f"{cid!r} is not a configuration of the dataset {dataset.path} (a plan's configuration "
                             "not measured: remove its line; the other images of its group stay grouped)")  # fmt: skip
    position = {str(dataset.configs[c]): j for j, c in enumerate(subset)}
    groups: dict[str, list[int]] = {}
    for cid, label in rows:
        j = position.get(cid)
        if j is not None and j in images:
            groups.setdefault(label, []).append(j)
    return list(groups.values())


def pair_observations(
    dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, exclude: set[tuple[str, str]] = frozenset()
) -> PairObservations:
    """The point-pair groups of the images of ``subset`` (configuration indices), as the
    module docstring describes; image indices are positions in ``subset``. Observations
    (config id, point) in ``exclude`` (rejected gross errors) are left out."""
    table = camera_points_table(dataset, settings)
    points = measured_table(dataset, "points", "pair")
    where = {name: i for i, name in enumerate(points.ids["point"])}
    images: dict[int, list[tuple[int, np.ndarray]]] = {}
    for index, point, xyz in rows_of(dataset, table, "point", subset):
        if (str(dataset.configs[subset[index]]), point) not in exclude:
            images.setdefault(index, []).append((where[point], xyz))
    groups: list[PairGroup] = []

    def label(j: int) -> tuple[str, str]:
        first = images[j][0][0]
        return str(points.ids["object"][first]), str(points.ids["side"][first])

    prescribed = _prescribed(dataset, settings, subset, images)
    named = {j for group in prescribed for j in group}
    rng = np.random.default_rng(settings.pairs.seed)
    order = [int(j) for j in rng.permutation(sorted(set(images) - named))]
    for group in prescribed + _grouped(order, [label(j) for j in order], settings, rng):
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
    return PairObservations(**subset_of(dataset, subset), groups=tuple(groups))
