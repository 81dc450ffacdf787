"""What the contact formulations share (self_contact, planes, tip_gauge): the contact elements
(balls on tips of a tree, dataset.yaml contact), their unknowns (centres on their tips and radii,
with the drawing's priors), the tips the kinematics give, the score against a simulation's truth
(the balls' centres, carried to W, the rigid motion removed), and, for a reading between two
elements (a contact, a gauge reading), its rows and their online and held-out observations."""

from __future__ import annotations

from abc import abstractmethod
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...data.dataset import ContactSetup, Dataset
from ...data.truth import FILE, Truth
from ..problem import Formulation, Observations, Problem, Rejection, Scored, measured_table, refuse_unstarted
from ..settings import MeasurementSettings
from ..state import Auxiliary, State

CENTRES = "contact_centres"
RADII = "contact_radii"


def contact_setup(dataset: Dataset, table: str) -> ContactSetup:
    """dataset.yaml contact (the dataset loader checked that a contacts table has it)."""
    if dataset.contact is None:
        raise InputError(dataset.path / "dataset.yaml", "contact", f"the {table} table needs the contact section")
    return dataset.contact


def element_tips(dataset: Dataset, names: Iterable[str]) -> tuple[str, ...]:
    return tuple(dataset.contact.elements[name].tip for name in names)


def tips_of(problem: Problem, tips: Iterable[str]) -> tuple[str, ...]:
    """The robot's tips (its order) that carry these elements: the kinematics' frames."""
    used = set(tips)
    return tuple(t for t in problem.robot.tip_names if t in used)


def frame_rows(frames: tuple[str, ...], tips: tuple[str, ...], elements: np.ndarray, configs: np.ndarray,
               n_configs: int) -> np.ndarray:  # fmt: skip
    """Per contact, the row of its element's tip at its configuration among frame-major poses."""
    tip = np.array([frames.index(t) for t in tips], dtype=int)
    return tip[elements] * n_configs + configs


def element_state(dataset: Dataset, names: tuple[str, ...], radii: bool = True) -> dict[str, Auxiliary]:
    """The elements' centres (and radii, where the measurements see them), started at the
    drawing's values, with its priors."""
    setup = dataset.contact
    centres = np.array([setup.elements[n].centre for n in names], dtype=float).reshape(-1, 3)
    out = {
        CENTRES: Auxiliary("points", centres, names, centres.reshape(-1), np.full(centres.size, setup.position_sigma_m))
    }
    if radii:
        values = np.array([setup.elements[n].radius for n in names], dtype=float)
        out[RADII] = Auxiliary("vector", values, names, values.copy(), np.full(len(values), setup.radius_sigma_m))
    return out


def true_elements(truth: Truth, names: tuple[str, ...], like: dict[str, Auxiliary]) -> dict[str, Auxiliary]:
    """The truth's values of the unknowns ``like`` (element_state's)."""
    missing = [n for n in names if n not in truth.contact_elements]
    if missing:
        raise InputError(
            FILE, "contact", f"the dataset names element {missing[0]!r}, which the simulation did not make"
        )
    centres = np.array([truth.contact_elements[n][0] for n in names], dtype=float).reshape(-1, 3)
    radii = np.array([truth.contact_elements[n][1] for n in names], dtype=float)
    out = {CENTRES: Auxiliary("points", centres, names, like[CENTRES].prior_mean, like[CENTRES].prior_sigmas)}
    if RADII in like:
        out[RADII] = Auxiliary("vector", radii, names, like[RADII].prior_mean, like[RADII].prior_sigmas)
    return out


def scored_elements(problem: Problem, state: State, tips: tuple[str, ...]) -> Scored:
    """The balls' centres on their tips (frame-major kinematics), in W."""
    frames = problem.frame
    on = np.array([frames.index(t) for t in tips], dtype=int)
    return Scored(state.value(CENTRES), points_from=CENTRES, tips=on)


def refuse_rare(path: Path, column: str, labels: np.ndarray, names: tuple[str, ...], least: int, message: str) -> None:
    """Each of ``names`` (indexed by ``labels``) measured at least ``least`` times in the fitting
    set, else an error whose ``message`` formats ``name`` and its count ``n``."""
    counts = Counter(labels.tolist())
    for k, name in enumerate(names):
        if counts[k] < least:
            raise InputError(path, column, message.format(name=name, n=counts[k]))


def element_pairs(
    dataset: Dataset, table: str, subset: np.ndarray, names: tuple[str, ...] | None
) -> tuple[np.ndarray, tuple[str, ...], dict[str, np.ndarray], np.ndarray]:
    """The rows of ``table`` (columns element_a, element_b) at configurations ``subset`` between
    the elements ``names`` (None: every element they name, sorted; others left out): the subset's
    configurations that have rows (the kinematics are evaluated at each), the names, per row its
    configuration (index into them) and elements (``configs``, ``elements_a``, ``elements_b``),
    and the rows' indices in the table."""
    rows_of = dataset.tables[table]
    index_of = dataset.config_index(rows_of.ids["config"])
    subset = np.asarray(subset, dtype=int)[np.isin(subset, index_of)]
    position = {int(c): i for i, c in enumerate(subset)}
    rows = [(k, position[int(c)], a, b) for k, (c, a, b) in enumerate(zip(
        index_of, rows_of.ids["element_a"], rows_of.ids["element_b"], strict=True)) if int(c) in position]  # fmt: skip
    if names is None:
        names = tuple(sorted({e for _, _, a, b in rows for e in (a, b)}))
    index = {name: i for i, name in enumerate(names)}
    rows = [r for r in rows if r[2] in index and r[3] in index]
    columns = {
        "configs": np.array([r[1] for r in rows], dtype=int),
        "elements_a": np.array([index[r[2]] for r in rows], dtype=int),
        "elements_b": np.array([index[r[3]] for r in rows], dtype=int),
    }
    return subset, names, columns, np.array([r[0] for r in rows], dtype=int)


class OnTips(Formulation):
    """A formulation of contact elements on a tree's tips: its kinematics are the tips that carry
    its elements, no instrument fixes W (the score against the truth removes a rigid motion), and
    that score is of the elements' centres."""

    frame = "flange"
    score_width = 1
    score_vectors = False

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        return tips_of(problem, problem.observations.tips)

    def scored(self, problem: Problem, state: State) -> Scored:
        return scored_elements(problem, state, problem.observations.tips)


class BetweenElements(OnTips):
    """A reading between two elements at a configuration (its table's columns element_a and
    element_b, the table named as ``kind``): self-contacts and gauge readings."""

    @abstractmethod
    def observations_of(self, dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None) -> Observations:
        """The readings at configurations ``subset`` between the elements ``names`` (None: every
        element they name)."""

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's readings between the elements the run started with (their centres
        are its unknowns)."""
        table = measured_table(dataset, self.kind, self.name)
        mine = np.isin(dataset.config_index(table.ids["config"]), subset)
        seen = [*table.ids["element_a"][mine], *table.ids["element_b"][mine]]
        refuse_unstarted(seen, like.names, dataset.path / f"{self.kind}.csv", "element_a", "element",
                         "its centre is not estimated")  # fmt: skip
        return self.observations_of(dataset, subset, like.names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        observations = self.observations_of(problem.dataset, problem.test, problem.observations.names)
        return (observations if len(observations.configs) else None), []

    def unit_tips(self, problem: Problem, observations: Observations) -> np.ndarray | None:
        return np.array(observations.tips, dtype=object)[observations.elements_a]
