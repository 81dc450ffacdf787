"""Projection: pixels of known points on the calibration objects through OpenCV's camera model,
``z = project(K, dist, X(P, q)^-1 O p)`` (fgcal.factors.Projections), the camera on the flange.
Unknowns besides P (whose tool.* is the camera mounting): the objects' pose O = T_W_F and, when
the config says so, the intrinsics. Scored against held-out pixels by the reprojection error in
the object's plane; against the truth by a point in the camera frame in W, the rigid motion
removed (the fixture pose is estimated relative to the robot: W is tied to the nominal base)."""

from __future__ import annotations

import numpy as np

from ...core.se3 import so3_log
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, Projections, RobustLoss
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..plan_model import FlangeCamera, Planning
from ..problem import Formulation, HeldOut, Keys, Observations, Problem, Rejection, Scored
from ..settings import MeasurementSettings
from ..state import Auxiliary, State
from .common import (
    constant_intrinsics,
    depth_over_focal,
    fit_pixels,
    intrinsics_unknowns,
    pixel_errors,
    pixel_observations,
    pnp_per_image,
    require_pixels,
)


class Projection(Formulation):
    name = "projection"
    frame = "tool"
    unit = "px"
    kind = "pixels"
    settings_read = ("noise.pixel_sigma_px", "intrinsics", "pixels_from")
    score = "reprojection"
    score_width = 2
    score_vectors = False
    likely_causes = (
        "pixels matched to the wrong points, wrong intrinsics, a camera mounting far from the dataset's, or joint "
        "angles in other units than units: declares"
    )
    instrument = "camera"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.pixel_px

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def planning(self, settings: MeasurementSettings) -> Planning:
        return FlangeCamera(rotation=True)

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
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
        # Nobody measured the mounting or the fixture: both start from the images.
        T_C_F = pnp_per_image(problem.dataset, problem.observations)
        params = with_mounting(problem, problem.robot.parameter_vector(), hand_eye_mounting(problem, T_C_F))
        aux = {"fixture": Auxiliary("pose3", initial_fixture_pose(problem, params, T_C_F))}
        return State(params, {**aux, **intrinsics_unknowns(problem.dataset, problem.settings)})

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
            Projections(
                kinematics,
                keys.params,
                keys["fixture"],
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
        return Scored(camera_work_point(problem.dataset)[None, :], extra={"camera_origin": np.zeros(3)})

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        # The true tool.* perturbs the simulation's nominal mounting, which a dataset's (or a
        # user's) mounting guess need not equal.
        robot = problem.dataset.robot.with_model(truth.model).with_tool(truth.camera_mounting_nominal)
        return robot, State(
            robot.parameter_vector(truth.parameters), {"fixture": Auxiliary("pose3", truth.fixture_pose)}
        )


def camera_work_point(dataset: Dataset) -> np.ndarray:
    """Where the camera works: the mean measured point in the camera frame (m), or its origin."""
    table = dataset.tables.get("camera_points")
    return table.values.mean(axis=0) if table is not None and len(table) else np.zeros(3)


def hand_eye_mounting(problem: Problem, T_C_F: dict[int, np.ndarray]) -> np.ndarray:
    """Camera mounting T_n_C from OpenCV's calibrateHandEye (Park), with the flange poses of
    the nominal model and the per-image target poses."""
    import cv2  # loaded when used: commands without images or cameras skip it

    flange = problem.robot.fk(problem.observations.q)
    images = sorted(T_C_F)
    R, t = cv2.calibrateHandEye(
        [flange[j][:3, :3] for j in images],
        [flange[j][:3, 3] for j in images],
        [T_C_F[j][:3, :3] for j in images],
        [T_C_F[j][:3, 3] for j in images],
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, np.ravel(t)
    return T


def with_mounting(problem: Problem, params: np.ndarray, T_n_C: np.ndarray) -> np.ndarray:
    """Parameters whose tool.* perturbation turns the nominal mounting into ``T_n_C``."""
    local = np.linalg.inv(problem.robot.tool_pose) @ T_n_C
    names = problem.robot.parameter_names
    out = params.copy()
    out[names.index("tool.tx") : names.index("tool.tz") + 1] = local[:3, 3]
    out[names.index("tool.rx") : names.index("tool.rz") + 1] = so3_log(local[:3, :3])
    return out


def initial_fixture_pose(problem: Problem, params: np.ndarray, T_C_F: dict[int, np.ndarray]) -> np.ndarray:
    """T_W_F from the images: per-image T_C_F composed with the current camera pose, the
    rotations averaged (chordal mean), the translations by their median."""
    T_W_C = problem.robot.fk_tool(problem.observations.q, problem.robot.parameter_dict(params))
    stacked = np.array([T_W_C[j] @ T for j, T in T_C_F.items()])
    U, _, Vt = np.linalg.svd(stacked[:, :3, :3].sum(axis=0))
    T = np.eye(4)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T[:3, 3] = np.median(stacked[:, :3, 3], axis=0)
    return T
