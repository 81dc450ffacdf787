"""Tip-to-tip gauge: a ballbar (or any known distance) between balls on two tips of a tree, read
at many configurations (fgcal.factors.TipDistances): the two hands holding a bar between them.
What gives a robot that measures itself (self-contact, planes) its scale: a contact's only length
is a ball's radius. Unknowns besides P: the balls' centres on their tips (priors from the drawing,
dataset.yaml contact). Scored against held-out readings by the distance, against the truth by the
balls' centres in W, the rigid motion removed (nothing here fixes W)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss, TipDistances
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import (
    Formulation,
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
from ..state import State
from .contact import (
    CENTRES,
    contact_setup,
    element_state,
    element_tips,
    frame_rows,
    scored_elements,
    tips_of,
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


class TipGauge(Formulation):
    name = "tip_gauge"
    frame = "flange"
    kind = "tip_distances"
    settings_read = ("noise.distance_sigma",)
    score = "distance"
    score_width = 1
    score_vectors = False
    likely_causes = (
        "readings that do not belong to their configurations, a gauge's deviation from its nominal length instead "
        "of its full length, the balls swapped between tips, joint angles in other units than units: declares"
    )
    instrument = "tip_gauge"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.distance_m

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        return tips_of(problem, problem.observations.tips)

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        measured_table(dataset, "tip_distances", self.name)
        contact_setup(dataset, "tip_distances")
        observations = _observations(dataset, fit, None)
        path = dataset.path / "tip_distances.csv"
        if not len(observations.configs):
            raise InputError(path, None, "no gauge reading in the fitting set")
        counts = Counter([*observations.elements_a.tolist(), *observations.elements_b.tolist()])
        for k, name in enumerate(observations.names):
            if counts[k] < 3:
                raise InputError(path, "element_a", f"element {name!r} has {counts[k]} readings in the fitting set: "
                                 "each needs many, in clearly different configurations")  # fmt: skip
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's gauge readings between the elements the run started with (their
        centres are its unknowns)."""
        table = measured_table(dataset, "tip_distances", self.name)
        mine = np.isin(dataset.config_index(table.ids["config"]), subset)
        seen = [*table.ids["element_a"][mine], *table.ids["element_b"][mine]]
        refuse_unstarted(seen, like.names, dataset.path / "tip_distances.csv", "element_a", "element",
                         "its centre is not estimated")  # fmt: skip
        return _observations(dataset, subset, like.names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        observations = _observations(problem.dataset, problem.test, problem.observations.names)
        return (observations if len(observations.configs) else None), []

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

    def scored(self, problem: Problem, state: State) -> Scored:
        return scored_elements(problem, state, problem.observations.tips)

    def unit_tips(self, problem: Problem, observations: Observations) -> np.ndarray | None:
        return np.array(observations.tips, dtype=object)[observations.elements_a]

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        names = problem.observations.names
        like = element_state(problem.dataset, names, radii=False)
        aux = true_contact_elements(truth, names, like)
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None) -> GaugeObservations:
    """The readings at configurations ``subset`` between the elements ``names`` (None: every
    element they name, sorted; others left out)."""
    table = dataset.tables["tip_distances"]
    index_of = dataset.config_index(table.ids["config"])
    # Only the configurations of this table: the kinematics are evaluated at each.
    subset = np.asarray(subset, dtype=int)[np.isin(subset, index_of)]
    position = {int(c): i for i, c in enumerate(subset)}
    rows = [(position[int(c)], a, b, float(d)) for c, a, b, d in zip(
        index_of, table.ids["element_a"], table.ids["element_b"], table.values[:, 0], strict=True
    ) if int(c) in position]  # fmt: skip
    if names is None:
        names = tuple(sorted({e for _, a, b, _ in rows for e in (a, b)}))
    index = {name: i for i, name in enumerate(names)}
    rows = [r for r in rows if r[1] in index and r[2] in index]
    return GaugeObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        elements_a=np.array([index[r[1]] for r in rows], dtype=int),
        elements_b=np.array([index[r[2]] for r in rows], dtype=int),
        distances=np.array([r[3] for r in rows], dtype=float),
        names=names,
        tips=element_tips(dataset, names),
    )
