"""Tip-to-tip gauge: a ballbar (or any known distance) between balls on two tips of a tree, read
at many configurations (fgcal.factors.TipDistances): the two hands holding a bar between them.
What gives a robot that measures itself (self-contact, planes) its scale: a contact's only length
is a ball's radius. Unknowns besides P: the balls' centres on their tips (priors from the drawing,
dataset.yaml contact). Scored against held-out readings by the distance, against the truth by the
balls' centres in W, the rigid motion removed (nothing here fixes W)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss, TipDistances
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import Keys, Observations, Problem, measured_table, subset_of, take
from ..settings import MeasurementSettings
from ..state import State
from .contact import (
    CENTRES,
    BetweenElements,
    contact_setup,
    element_pairs,
    element_state,
    element_tips,
    frame_rows,
    refuse_rare,
)
from .contact import true_elements as true_contact_elements


@dataclass(frozen=True)
class GaugeObservations(Observations):
    configs: np.ndarray  # (O,) per reading: index into config_ids
    elements_a: np.ndarray  # (O,) index into names
    elements_b: np.ndarray  # (O,)
    distances: np.ndarray  # (O,) m
    names: tuple[str, ...]
    tips: tuple[str, ...]

    @property
    def n_residuals(self) -> int:
        return len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        a, b = self.names[self.elements_a[unit]], self.names[self.elements_b[unit]]
        return str(self.config_ids[self.configs[unit]]), f"{a}-{b}"

    def select(self, keep: np.ndarray) -> GaugeObservations:
        return GaugeObservations(
            self.config_ids, self.q, **take(self, keep, ("configs", "elements_a", "elements_b", "distances")),
            names=self.names, tips=self.tips,
        )  # fmt: skip


class TipGauge(BetweenElements):
    name = "tip_gauge"
    kind = "tip_distances"
    settings_read = ("noise.distance_sigma",)
    score = "distance"
    likely_causes = (
        "readings that do not belong to their configurations, a gauge's deviation from its nominal length instead "
        "of its full length, the balls swapped between tips, joint angles in other units than units: declares"
    )
    instrument = "tip_gauge"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.distance_m

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        measured_table(dataset, "tip_distances", self.name)
        contact_setup(dataset, "tip_distances")
        observations = self.observations_of(dataset, fit, None)
        path = dataset.path / "tip_distances.csv"
        if not len(observations.configs):
            raise InputError(path, None, "no gauge reading in the fitting set")
        refuse_rare(path, "element_a", np.concatenate([observations.elements_a, observations.elements_b]),
                    observations.names, 3, "element {name!r} has {n} readings in the fitting set: each needs many, in "
                    "clearly different configurations")  # fmt: skip
        return observations

    def initial_state(self, problem: Problem) -> State:
        return State(problem.robot.parameter_vector(), element_state(problem.dataset, problem.observations.names,
                                                                     radii=False))  # fmt: skip

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        frames, n, tips = problem.frame, len(observations.q), problem.observations.tips
        return [
            TipDistances(
                kinematics,
                keys.params,
                keys[CENTRES],
                len(state.value(CENTRES)),
                frame_rows(frames, tips, observations.elements_a, observations.configs, n),
                frame_rows(frames, tips, observations.elements_b, observations.configs, n),
                observations.elements_a,
                observations.elements_b,
                observations.distances,
                problem.settings.noise.distance_m,
                robust=robust,
            )
        ]

    def observations_of(
        self, dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None
    ) -> GaugeObservations:
        """The readings at configurations ``subset`` between the elements ``names`` (None: every
        element they name, sorted; others left out)."""
        subset, names, columns, rows = element_pairs(dataset, "tip_distances", subset, names)
        return GaugeObservations(
            **subset_of(dataset, subset), **columns,
            distances=dataset.tables["tip_distances"].values[rows, 0].astype(float),
            names=names, tips=element_tips(dataset, names),
        )  # fmt: skip

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        names = problem.observations.names
        like = element_state(problem.dataset, names, radii=False)
        aux = true_contact_elements(truth, names, like)
        return robot, State(robot.parameter_vector(truth.parameters), aux)
