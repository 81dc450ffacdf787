"""6D poses: a tracker's 6D probe (or any instrument measuring a pose of a frame on the flange),
``Z = L X(P, q) E`` (fgcal.factors.Poses). Unknowns besides P: the instrument's pose L = T_T_W
and the probe's frame on the flange E = T_n_E. Scored by the probe's origin in the tracker's
frame (no gauge), and by the angle between the predicted and measured orientations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...core.se3 import inverse, pose, quaternion_rotation
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, Poses, RobustLoss
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
    rows_of,
    subset_of,
    take,
)
from ..settings import MeasurementSettings
from ..state import Auxiliary, State
from .common import initial_pose_chain


@dataclass(frozen=True)
class PoseObservations(Observations):
    configs: np.ndarray  # (O,) per pose: index into config_ids
    measured: np.ndarray  # (O, 4, 4) T_T_E

    @property
    def n_residuals(self) -> int:
        return 6 * len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        return str(self.config_ids[self.configs[unit]]), "pose"

    def select(self, keep: np.ndarray) -> PoseObservations:
        return PoseObservations(self.config_ids, self.q, **take(self, keep, ("configs", "measured")))


class MeasuredPoses(Formulation):
    name = "poses"
    frame = "flange"
    kind = "tracker_poses"
    settings_read = ("noise.pose_sigma", "noise.pose_angle_sigma")
    score_width = 6
    score_rows = slice(3, 6)  # the position rows of each pose's Log
    likely_causes = (
        "poses that do not belong to their configurations (rows shifted), quaternions in another order than qw, qx, "
        "qy, qz or inverted poses (the instrument in the probe's frame), joint angles or lengths in other units than "
        "units: declares, or another robot than the one that moved"
    )
    instrument = "tracker_probe"

    def sigma(self, settings: MeasurementSettings) -> float:
        # A pose's whitened residual is counted in position sigmas.
        return settings.noise.pose_m

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        observations = _observations(dataset, fit)
        if len(observations.configs) < 3:
            raise InputError(
                dataset.path / "tracker_poses.csv", None,
                f"only {len(observations.configs)} poses in the fitting set: too few",
            )  # fmt: skip
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        return _observations(dataset, subset)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        observations = _observations(problem.dataset, problem.test)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        params = problem.robot.parameter_vector()
        observations = problem.observations
        flange = problem.robot.fk(observations.q, problem.robot.parameter_dict(params), tip=problem.frame)
        L, E = initial_pose_chain(flange[observations.configs], observations.measured)
        return State(params, {"tracker": Auxiliary("pose3", L), "tool_frame": Auxiliary("pose3", E)})

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        noise = problem.settings.noise
        return [
            Poses(
                kinematics,
                keys.params,
                keys["tracker"],
                keys["tool_frame"],
                observations.configs,
                list(observations.measured),
                noise.pose_rad,
                noise.pose_m,
                robust=robust,
            )
        ]

    def held_out_errors(self, problem: Problem, observations: Observations, state: State) -> dict[str, HeldOut]:
        """Per measured pose Z: the error vector (m) of the predicted origin of E, ``L X E``, in
        the instrument's frame, and the angle (rad) between the predicted and measured
        orientations."""
        motion = problem.dataset.motion_of(observations.config_ids)
        flange = problem.robot.fk(observations.q, problem.robot.parameter_dict(state.params), motion, tip=problem.frame)
        predicted = state.value("tracker") @ flange[observations.configs] @ state.value("tool_frame")
        measured = observations.measured
        relative = np.einsum("oji,ojk->oik", measured[:, :3, :3], predicted[:, :3, :3])
        angles = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
        return {
            "tool_point": HeldOut(predicted[:, :3, 3] - measured[:, :3, 3], observations.configs),
            "orientation_rad": HeldOut(angles, observations.configs),
        }

    def tool_frame(self, state: State) -> np.ndarray | None:
        return state.value("tool_frame").copy()  # the 6D probe's frame

    def scored(self, problem: Problem, state: State) -> Scored:
        # The probe's origin, in the tracker's frame.
        return Scored(state.value("tool_frame")[None, :3, 3], state.value("tracker"), "tool_frame", "tracker")

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        aux = {
            "tracker": Auxiliary("pose3", inverse(truth.tracker_pose)),
            "tool_frame": Auxiliary("pose3", truth.need("tracker_probe", "tracker_probe")),
        }
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(dataset: Dataset, subset: np.ndarray) -> PoseObservations:
    rows = list(rows_of(dataset, measured_table(dataset, "tracker_poses", "poses"), "config", subset))
    return PoseObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        measured=np.array([pose(quaternion_rotation(v[3:]), v[:3]) for _, _, v in rows]).reshape(-1, 4, 4),
    )
