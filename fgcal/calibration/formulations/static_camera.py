"""A static camera (eye-to-hand) watching a board on the flange, ``z = project(K, dist, L X(P, q)
B p)`` (fgcal.factors.StaticProjections). Unknowns besides P: the camera's pose L = T_C_W, the
board's mounting B = T_n_B and, when the config says so, the intrinsics. Scored against
held-out pixels by the reprojection error in the board's plane; against the truth by the
board's origin in W, the rigid motion removed: the robot's accuracy, not how well the camera
knows its own depth (its pose's uncertainty would otherwise dominate the score)."""

from __future__ import annotations

import numpy as np

from ...core.errors import InputError
from ...core.se3 import inverse
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss, StaticProjections
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..plan_model import Planning, StaticBoard
from ..problem import Formulation, HeldOut, Keys, Observations, Problem, Rejection, Scored
from ..settings import MeasurementSettings
from ..state import Auxiliary, State
from .common import (
    constant_intrinsics,
    depth_over_focal,
    fit_pixels,
    initial_pose_chain,
    intrinsics_unknowns,
    pixel_errors,
    pixel_observations,
    pnp_per_image,
    require_pixels,
)


class StaticCamera(Formulation):
    name = "static_camera"
    frame = "flange"
    unit = "px"
    kind = "pixels"
    settings_read = ("noise.pixel_sigma_px", "intrinsics", "pixels_from")
    score = "reprojection"
    score_width = 2
    score_vectors = False
    likely_causes = (
        "pixels matched to the wrong board points, wrong intrinsics, images that do not belong to their "
        "configurations, or joint angles in other units than units: declares"
    )
    instrument = "static_camera"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.pixel_px

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def planning(self, settings: MeasurementSettings) -> Planning:
        return StaticBoard()

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        if dataset.camera_mounting is not None:
            raise InputError(
                dataset.path / "dataset.yaml", "camera.mounting", "this camera is mounted on the flange: the "
                f"{self.name} formulation is for a camera fixed in the cell watching a board on the flange",
            )  # fmt: skip
        return fit_pixels(dataset, fit, self.name)

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        require_pixels(dataset, f"the {self.name} formulation needs")
        return pixel_observations(dataset, subset)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        observations = pixel_observations(problem.dataset, problem.test)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        # The board's pose in the camera per image (solvePnP), then the chain through the robot.
        T_C_B = pnp_per_image(problem.dataset, problem.observations)
        flange = problem.robot.fk(problem.observations.q, tip=problem.frame)
        images = sorted(T_C_B)
        L, E = initial_pose_chain(flange[images], np.array([T_C_B[j] for j in images]))
        aux = {"static_camera": Auxiliary("pose3", L), "tool_frame": Auxiliary("pose3", E)}
        return State(
            problem.robot.parameter_vector(), {**aux, **intrinsics_unknowns(problem.dataset, problem.settings)}
        )

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        return [
            StaticProjections(
                kinematics,
                keys.params,
                keys["static_camera"],
                keys["tool_frame"],
                observations.configs,
                observations.points,
                observations.pixels,
                problem.settings.noise.pixel_px,
                intrinsics=constant_intrinsics(problem.dataset, state),
                intrinsics_key=keys.aux.get("intrinsics"),
                robust=robust,
            )
        ]

    def metric_scale(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> np.ndarray:
        return depth_over_focal(problem, main, inputs, state)

    def extra_errors(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> dict[str, HeldOut]:
        return pixel_errors(problem, main, inputs, state)

    def scored(self, problem: Problem, state: State) -> Scored:
        # The board's origin, in W.
        return Scored(state.value("tool_frame")[None, :3, 3], points_from="tool_frame")

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        aux = {
            "static_camera": Auxiliary("pose3", inverse(truth.need("static_camera_pose", "static_camera.pose"))),
            "tool_frame": Auxiliary("pose3", truth.need("static_camera_board_mount", "static_camera.board_mount")),
        }
        return robot, State(robot.parameter_vector(truth.parameters), aux)
