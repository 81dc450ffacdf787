"""Self-contact: a robot with several chains touches itself, a ball on one tip against a ball on
another (two hands meeting), at many configurations (fgcal.factors.SelfContacts). No instrument:
each contact says that the balls' centres are the sum of their radii apart, which closes the
loop through the tree (both arms meet in the torso). Unknowns besides P: the balls' centres on
their tips and their radii (priors from the drawing, dataset.yaml contact). What a common rigid
motion of the whole robot does, or the chain the loop never passes through, no contact sees:
identifiability fixes it. Scored against held-out contacts by how far from touching the
calibrated model puts them, against the truth by the balls' centres in W, the rigid motion
removed."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss, SelfContacts
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
    RADII,
    contact_setup,
    element_state,
    element_tips,
    frame_rows,
    scored_elements,
    tips_of,
)
from .contact import true_elements as true_contact_elements


@dataclass(frozen=True)
class ContactObservations(Observations):
    configs: np.ndarray  # (O,) per contact: index into config_ids
    elements_a: np.ndarray  # (O,) index into names
    elements_b: np.ndarray  # (O,)
    names: tuple[str, ...]  # the elements the fit estimates
    tips: tuple[str, ...]  # per name, its tip

    @property
    def n_residuals(self) -> int:
        return len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        a, b = self.names[self.elements_a[unit]], self.names[self.elements_b[unit]]
        return str(self.config_ids[self.configs[unit]]), f"{a}-{b}"

    def select(self, keep: np.ndarray) -> ContactObservations:
        return ContactObservations(
            self.config_ids, self.q, **take(self, keep, ("configs", "elements_a", "elements_b")), names=self.names,
            tips=self.tips,
        )  # fmt: skip


class SelfContact(Formulation):
    name = "self_contact"
    frame = "flange"
    kind = "contacts"
    settings_read = ("noise.contact_sigma",)
    score = "contact"
    score_width = 1
    score_vectors = False
    likely_causes = (
        "contacts that do not belong to their configurations (rows shifted), elements swapped between hands, the "
        "elements' tips or drawings wrong in dataset.yaml contact, joint angles in other units than units: declares"
    )
    instrument = "self_contact"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.contact_m

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        return tips_of(problem, problem.observations.tips)

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        measured_table(dataset, "contacts", self.name)
        contact_setup(dataset, "contacts")
        observations = _observations(dataset, fit, None)
        if not len(observations.configs):
            raise InputError(dataset.path / "contacts.csv", None, "no contact in the fitting set")
        counts = Counter([*observations.elements_a.tolist(), *observations.elements_b.tolist()])
        for k, name in enumerate(observations.names):
            if counts[k] < 3:
                raise InputError(
                    dataset.path / "contacts.csv", "element_a",
                    f"element {name!r} touches {counts[k]} times in the fitting set: each element needs many "
                    "contacts, in clearly different configurations",
                )  # fmt: skip
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's contacts between the elements the run started with (their centres
        and radii are its unknowns)."""
        table = measured_table(dataset, "contacts", self.name)
        mine = np.isin(dataset.config_index(table.ids["config"]), subset)
        seen = [*table.ids["element_a"][mine], *table.ids["element_b"][mine]]
        refuse_unstarted(seen, like.names, dataset.path / "contacts.csv", "element_a", "element",
                         "its centre is not estimated")  # fmt: skip
        return _observations(dataset, subset, like.names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        observations = _observations(problem.dataset, problem.test, problem.observations.names)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        return State(problem.robot.parameter_vector(), element_state(problem.dataset, problem.observations.names))

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        frames, n = problem.frame, len(observations.q)
        tips = problem.observations.tips
        return [
            SelfContacts(
                kinematics,
                keys.params,
                keys[CENTRES],
                keys[RADII],
                len(state.value(CENTRES)),
                frame_rows(frames, tips, observations.elements_a, observations.configs, n),
                frame_rows(frames, tips, observations.elements_b, observations.configs, n),
                observations.elements_a,
                observations.elements_b,
                problem.settings.noise.contact_m,
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
        aux = true_contact_elements(truth, names, element_state(problem.dataset, names))
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None) -> ContactObservations:
    """The contacts at configurations ``subset`` between the elements ``names`` (None: every
    element they touch, named in sorted order; others left out)."""
    table = dataset.tables["contacts"]
    index_of = dataset.config_index(table.ids["config"])
    # Only the configurations of this table: the kinematics are evaluated at each.
    subset = np.asarray(subset, dtype=int)[np.isin(subset, index_of)]
    position = {int(c): i for i, c in enumerate(subset)}
    rows = [(position[int(c)], a, b) for c, a, b in zip(index_of, table.ids["element_a"], table.ids["element_b"],
                                                        strict=True) if int(c) in position]  # fmt: skip
    if names is None:
        names = tuple(sorted({e for _, a, b in rows for e in (a, b)}))
    index = {name: i for i, name in enumerate(names)}
    rows = [r for r in rows if r[1] in index and r[2] in index]
    return ContactObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        elements_a=np.array([index[r[1]] for r in rows], dtype=int),
        elements_b=np.array([index[r[2]] for r in rows], dtype=int),
        names=names,
        tips=element_tips(dataset, names),
    )
