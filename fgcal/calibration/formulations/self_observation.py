"""Self-observation: cameras on a link of one chain (a torso) see checkerboards on the tips of
others (the hands), ``z = project(K, (Y(P, q) M)^-1 X(P, q) B p)`` (fgcal.factors.LinkProjections):
projection through both chains. Unknowns besides P: each camera's mounting on its link M and each
board's pose on its tip B (started at dataset.yaml self_observation's nominal values); the
intrinsics are known (the cameras' own calibration). Scored against held-out pixels by the
reprojection error in the board's plane; against the truth by the origins of the boards' tips in W,
the rigid motion removed (nothing here fixes W)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import FILE, Truth
from ...factors import LinkProjections, MeasurementSet, RobustLoss
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import (
    Formulation,
    HeldOut,
    Keys,
    Observations,
    Problem,
    Rejection,
    Scored,
    measured_table,
    refuse_unstarted,
    subset_of,
    take,
)
from ..settings import MeasurementSettings
from ..state import Auxiliary, State

MOUNTING, BOARD = "mounting.", "board."


@dataclass(frozen=True)
class ObservedPixels(Observations):
    configs: np.ndarray  # (O,) per pixel: index into config_ids
    cameras: np.ndarray  # (O,) index into camera_names
    boards: np.ndarray  # (O,) index into board_names
    points: np.ndarray  # (O, 3) the point in its board's frame, m
    pixels: np.ndarray  # (O, 2) px
    names: np.ndarray  # (O,) the points' names
    camera_names: tuple[str, ...]
    board_names: tuple[str, ...]

    @property
    def n_residuals(self) -> int:
        return 2 * len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        return str(self.config_ids[self.configs[unit]]), f"{self.board_names[self.boards[unit]]}.{self.names[unit]}"

    def select(self, keep: np.ndarray) -> ObservedPixels:
        return ObservedPixels(
            self.config_ids, self.q, **take(self, keep, ("configs", "cameras", "boards", "points", "pixels", "names")),
            camera_names=self.camera_names, board_names=self.board_names,
        )  # fmt: skip


class SelfObservation(Formulation):
    name = "self_observation"
    frame = "flange"
    unit = "px"
    kind = "observed_pixels"
    settings_read = ("noise.pixel_sigma_px",)
    score = "reprojection"
    score_width = 2
    score_vectors = False
    likely_causes = (
        "pixels matched to the wrong board points or cameras, wrong intrinsics, a camera's link or a board's tip "
        "wrong in dataset.yaml self_observation, joint angles in other units than units: declares"
    )
    instrument = "self_observation"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.pixel_px

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        """The cameras' links (tips of their names) and the boards' tips, in the robot's order."""
        observations, dataset = problem.observations, problem.dataset
        used = {*observations.camera_names, *(dataset.tip_boards[b].tip for b in observations.board_names)}
        return tuple(t for t in problem.robot.tip_names if t in used)

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        table = measured_table(dataset, "observed_pixels", self.name)
        # Every camera and board of the table, not only those the fitting split kept: one the split
        # left with no image would be scored on a mounting never fitted.
        cameras, boards = (tuple(sorted(set(table.ids[column]))) for column in ("camera", "board"))
        observations = _observations(dataset, fit, cameras, boards)
        if not len(observations.configs):
            raise InputError(
                dataset.path / "observed_pixels.csv", "config", f"none of its {len(set(table.ids['config']))} "
                "configurations is in the fitting split (validation: split: ordered holds out the last ones)",
            )  # fmt: skip
        for column, labels, names in (("camera", observations.cameras, cameras),
                                      ("board", observations.boards, boards)):  # fmt: skip
            for k, name in enumerate(names):
                seen = len(np.unique(observations.configs[labels == k]))
                if seen < 3:
                    raise InputError(
                        dataset.path / "observed_pixels.csv", column, f"{column} {name!r} is in {seen} images of the "
                        "fitting set: each needs several, in clearly different configurations",
                    )  # fmt: skip
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's pixels of the cameras and boards the run started with (their
        mountings and poses are its unknowns)."""
        table = measured_table(dataset, "observed_pixels", self.name)
        mine = np.isin(dataset.config_index(table.ids["config"]), subset)
        path = dataset.path / "observed_pixels.csv"
        refuse_unstarted(table.ids["camera"][mine], like.camera_names, path, "camera", "camera",
                         "its mounting is not estimated")  # fmt: skip
        refuse_unstarted(table.ids["board"][mine], like.board_names, path, "board", "board",
                         "its pose on its tip is not estimated")  # fmt: skip
        return _observations(dataset, subset, like.camera_names, like.board_names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        fitted = problem.observations
        observations = _observations(problem.dataset, problem.test, fitted.camera_names, fitted.board_names)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        dataset, observations = problem.dataset, problem.observations
        aux = {MOUNTING + c: Auxiliary("pose3", dataset.link_cameras[c].mounting) for c in observations.camera_names}
        aux.update({BOARD + b: Auxiliary("pose3", dataset.tip_boards[b].pose) for b in observations.board_names})
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
        fitted, dataset, frames = problem.observations, problem.dataset, problem.frame
        n = len(observations.q)
        camera_rows = np.array([frames.index(c) for c in fitted.camera_names], dtype=int)
        board_rows = np.array([frames.index(dataset.tip_boards[b].tip) for b in fitted.board_names], dtype=int)
        intrinsics = np.array([_intrinsics(dataset, c) for c in fitted.camera_names])
        return [
            LinkProjections(
                kinematics,
                keys.params,
                [keys[MOUNTING + c] for c in fitted.camera_names],
                [keys[BOARD + b] for b in fitted.board_names],
                camera_rows[observations.cameras] * n + observations.configs,
                board_rows[observations.boards] * n + observations.configs,
                observations.cameras,
                observations.boards,
                observations.points,
                observations.pixels,
                problem.settings.noise.pixel_px,
                intrinsics,
                robust=robust,
            )
        ]

    def metric_scale(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> np.ndarray:
        """Per pixel, its point's depth over its camera's mean focal length."""
        depth = main.camera_points(inputs)[-1][:, 2]
        return depth / (0.5 * (main.intrinsics[main.cameras, 0] + main.intrinsics[main.cameras, 1]))

    def extra_errors(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> dict[str, HeldOut]:
        pixels = np.linalg.norm(main.compute(inputs, False).residual.reshape(-1, 2), axis=1)
        return {"reprojection_px": HeldOut(pixels, np.asarray(main.configs))}

    def scored(self, problem: Problem, state: State) -> Scored:
        """The origins of the boards' tips (the hands), in W: points on the robot that the
        estimate and the truth share (a board's own pose is an unknown of its own)."""
        tips = []
        for board in problem.observations.board_names:
            tip = problem.frame.index(problem.dataset.tip_boards[board].tip)
            if tip not in tips:
                tips.append(tip)
        return Scored(np.zeros((len(tips), 3)), tips=np.array(tips, dtype=int))

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        observations, aux = problem.observations, {}
        for prefix, names, true in ((MOUNTING, observations.camera_names, truth.link_cameras),
                                    (BOARD, observations.board_names, truth.tip_boards)):  # fmt: skip
            for name in names:
                if name not in true:
                    raise InputError(FILE, "self_observation", f"the dataset names {name!r}, which the simulation "
                                     "did not make")  # fmt: skip
                aux[prefix + name] = Auxiliary("pose3", true[name])
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _intrinsics(dataset: Dataset, camera: str) -> np.ndarray:
    c = dataset.link_cameras[camera].camera
    return np.array([c.fx, c.fy, c.cx, c.cy, *c.distortion])


def _observations(
    dataset: Dataset, subset: np.ndarray, cameras: tuple[str, ...] | None, boards: tuple[str, ...] | None
) -> ObservedPixels:
    """The pixels at configurations ``subset`` of the cameras and boards named (None: those they
    name, sorted; others left out)."""
    table = dataset.tables["observed_pixels"]
    index_of = dataset.config_index(table.ids["config"])
    subset = np.asarray(subset, dtype=int)[np.isin(subset, index_of)]  # the kinematics are evaluated at each
    position = {int(c): i for i, c in enumerate(subset)}
    rows = [k for k, c in enumerate(index_of) if int(c) in position]
    if cameras is None:
        cameras = tuple(sorted({table.ids["camera"][k] for k in rows}))
        boards = tuple(sorted({table.ids["board"][k] for k in rows}))
    camera_index = {n: i for i, n in enumerate(cameras)}
    board_index = {n: i for i, n in enumerate(boards)}
    rows = [k for k in rows if table.ids["camera"][k] in camera_index and table.ids["board"][k] in board_index]
    points = []
    for k in rows:
        board = dataset.tip_boards[table.ids["board"][k]]
        points.append(board.points[board.point_names.index(table.ids["point"][k])])
    return ObservedPixels(
        **subset_of(dataset, subset),
        configs=np.array([position[int(index_of[k])] for k in rows], dtype=int),
        cameras=np.array([camera_index[table.ids["camera"][k]] for k in rows], dtype=int),
        boards=np.array([board_index[table.ids["board"][k]] for k in rows], dtype=int),
        points=np.array(points, dtype=float).reshape(-1, 3),
        pixels=table.values[rows].reshape(-1, 2),
        names=np.array([table.ids["point"][k] for k in rows], dtype=object),
        camera_names=cameras,
        board_names=boards,
    )
