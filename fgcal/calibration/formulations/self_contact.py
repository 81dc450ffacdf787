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

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss, SelfContacts
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import Keys, Observations, Problem, measured_table, subset_of, take
from ..settings import MeasurementSettings
from ..state import State
from .contact import (
    CENTRES,
    RADII,
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


class SelfContact(BetweenElements):
    name = "self_contact"
    kind = "contacts"
    settings_read = ("noise.contact_sigma",)
    score = "contact"
    likely_causes = (
        "contacts that do not belong to their configurations (rows shifted), elements swapped between hands, the "
        "elements' tips or drawings wrong in dataset.yaml contact, joint angles in other units than units: declares"
    )
    instrument = "self_contact"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.contact_m

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        measured_table(dataset, "contacts", self.name)
        contact_setup(dataset, "contacts")
        observations = self.observations_of(dataset, fit, None)
        path = dataset.path / "contacts.csv"
        if not len(observations.configs):
            raise InputError(path, None, "no contact in the fitting set")
        refuse_rare(path, "element_a", np.concatenate([observations.elements_a, observations.elements_b]),
                    observations.names, 3, "element {name!r} touches {n} times in the fitting set: each element needs "
                    "many contacts, in clearly different configurations")  # fmt: skip
        return observations

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

    def observations_of(
        self, dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None
    ) -> ContactObservations:
        """The contacts at configurations ``subset`` between the elements ``names`` (None: every
        element they touch, named in sorted order; others left out)."""
        subset, names, columns, _ = element_pairs(dataset, "contacts", subset, names)
        return ContactObservations(**subset_of(dataset, subset), **columns, names=names,
                                   tips=element_tips(dataset, names))  # fmt: skip

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        names = problem.observations.names
        aux = true_contact_elements(truth, names, element_state(problem.dataset, names))
        return robot, State(robot.parameter_vector(truth.parameters), aux)
