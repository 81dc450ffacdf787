"""Planes: a robot touches planes of its cell (a table below its hands, a wall in front) with a
ball on a tip, at many configurations (fgcal.factors.PlaneContacts). No instrument: each contact
says that the ball's centre is its radius away from the plane. Unknowns besides P: the planes
(normal and offset; a prior from the cell's drawing when dataset.yaml contact states one), the
balls' centres on their tips and their radii (priors from the drawing). A common rigid motion of
the robot and its planes no contact sees: scored against the truth by the balls' centres in W,
the rigid motion removed; against held-out contacts by how far from touching the calibrated
model puts them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import FILE, Truth
from ...factors import MeasurementSet, PlaneContacts, RobustLoss
from ...factors.contact import complement_basis
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import Keys, Observations, Problem, Rejection, measured_table, refuse_unstarted, subset_of, take
from ..settings import MeasurementSettings
from ..state import Auxiliary, State
from .contact import (
    CENTRES,
    RADII,
    OnTips,
    contact_setup,
    element_state,
    element_tips,
    frame_rows,
    refuse_rare,
)
from .contact import true_elements as true_contact_elements

PLANES = "contact_planes"


@dataclass(frozen=True)
class PlaneObservations(Observations):
    configs: np.ndarray  # (O,) per contact: index into config_ids
    elements: np.ndarray  # (O,) index into names
    planes: np.ndarray  # (O,) index into plane_names
    names: tuple[str, ...]  # the elements the fit estimates
    tips: tuple[str, ...]  # per name, its tip
    plane_names: tuple[str, ...]

    @property
    def n_residuals(self) -> int:
        return len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        element, plane = self.names[self.elements[unit]], self.plane_names[self.planes[unit]]
        return str(self.config_ids[self.configs[unit]]), f"{element}-{plane}"

    def select(self, keep: np.ndarray) -> PlaneObservations:
        return PlaneObservations(
            self.config_ids, self.q, **take(self, keep, ("configs", "elements", "planes")), names=self.names,
            tips=self.tips, plane_names=self.plane_names,
        )  # fmt: skip


class Planes(OnTips):
    name = "planes"
    kind = "plane_contacts"
    settings_read = ("noise.contact_sigma",)
    score = "contact"
    likely_causes = (
        "contacts that do not belong to their configurations (rows shifted), planes or elements swapped, a plane's "
        "nominal normal pointing away from the side the robot touches, joint angles in other units than units: declares"
    )
    instrument = "planes"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.contact_m

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        measured_table(dataset, "plane_contacts", self.name)
        contact_setup(dataset, "plane_contacts")
        observations = _observations(dataset, fit, None, None)
        path = dataset.path / "plane_contacts.csv"
        if not len(observations.configs):
            raise InputError(path, None, "no plane contact in the fitting set")
        for column, labels, names in (("plane", observations.planes, observations.plane_names),
                                      ("element", observations.elements, observations.names)):  # fmt: skip
            refuse_rare(path, column, labels, names, 4, f"{column} {{name!r}} has {{n}} contacts in the fitting set: "
                        "each needs many, in clearly different configurations")  # fmt: skip
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's contacts of the elements with the planes the run started with (the
        elements' centres and radii and the planes are its unknowns)."""
        table = measured_table(dataset, "plane_contacts", self.name)
        mine = np.isin(dataset.config_index(table.ids["config"]), subset)
        path = dataset.path / "plane_contacts.csv"
        refuse_unstarted(table.ids["element"][mine], like.names, path, "element", "element",
                         "its centre is not estimated")  # fmt: skip
        refuse_unstarted(table.ids["plane"][mine], like.plane_names, path, "plane", "plane", "it is not estimated")
        return _observations(dataset, subset, like.names, like.plane_names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        fitted = problem.observations
        observations = _observations(problem.dataset, problem.test, fitted.names, fitted.plane_names)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        """The elements at the drawing's values; each plane's normal nominal, its offset where
        the nominal robot puts the balls that touch it."""
        dataset, observations = problem.dataset, problem.observations
        params = problem.robot.parameter_vector()
        aux = element_state(dataset, observations.names)
        normals = _nominal_normals(dataset, observations.plane_names)
        frames = self.frames(problem)
        tips = observations.tips
        poses = np.concatenate([problem.robot.fk(observations.q, problem.robot.parameter_dict(params), tip=t)
                                for t in frames])  # fmt: skip
        rows = frame_rows(frames, tips, observations.elements, observations.configs, len(observations.q))
        centres, radii = aux[CENTRES].value, aux[RADII].value
        balls = np.einsum("oij,oj->oi", poses[rows, :3, :3], centres[observations.elements]) + poses[rows, :3, 3]
        planes = np.zeros((len(normals), 3))
        for k, normal in enumerate(normals):
            mine = observations.planes == k
            planes[k, 2] = np.mean(balls[mine] @ normal - radii[observations.elements[mine]])
        prior = _plane_prior(dataset, observations.plane_names)
        aux[PLANES] = Auxiliary("vector", planes.reshape(-1), plane_labels(observations.plane_names), *prior)
        return State(params, aux)

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        fitted = problem.observations
        return [
            PlaneContacts(
                kinematics,
                keys.params,
                keys[CENTRES],
                keys[RADII],
                keys[PLANES],
                len(state.value(CENTRES)),
                _nominal_normals(problem.dataset, fitted.plane_names),
                frame_rows(problem.frame, fitted.tips, observations.elements, observations.configs,
                           len(observations.q)),
                observations.elements,
                observations.planes,
                problem.settings.noise.contact_m,
                robust=robust,
            )
        ]  # fmt: skip

    def unit_tips(self, problem: Problem, observations: Observations) -> np.ndarray | None:
        return np.array(observations.tips, dtype=object)[observations.elements]

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        observations = problem.observations
        aux = true_contact_elements(truth, observations.names, element_state(problem.dataset, observations.names))
        nominal = _nominal_normals(problem.dataset, observations.plane_names)
        planes = []
        for name, n0 in zip(observations.plane_names, nominal, strict=True):
            if name not in truth.contact_planes:
                raise InputError(
                    FILE, "contact", f"the dataset names plane {name!r}, which the simulation did not make"
                )
            normal, offset = truth.contact_planes[name]
            normal = np.asarray(normal) / np.linalg.norm(normal)
            # The chart's coordinates of the true normal: n0 + B a is parallel to it.
            planes.append([*(complement_basis(n0).T @ normal / (n0 @ normal)), offset])
        labels = plane_labels(observations.plane_names)
        aux[PLANES] = Auxiliary("vector", np.array(planes, dtype=float).reshape(-1), labels)
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def plane_labels(names: tuple[str, ...]) -> tuple[str, ...]:
    """A plane's three entries: its normal's tilt off the nominal in the chart's two directions
    (about rad for small tilts) and its offset (m)."""
    return tuple(f"{name}.{entry}" for name in names for entry in ("tilt_1", "tilt_2", "offset_m"))


def _nominal_normals(dataset: Dataset, names: tuple[str, ...]) -> np.ndarray:
    return np.array([dataset.contact.planes[n][0] for n in names], dtype=float).reshape(-1, 3)


def _plane_prior(dataset: Dataset, names: tuple[str, ...]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The drawing's planes as a prior (the chart's origin, the nominal offset), when dataset.yaml
    contact states its sigmas; else none. An unstated part is no prior to speak of (1 km, 1000 rad)."""
    setup = dataset.contact
    if setup.plane_angle_sigma_rad is None and setup.plane_offset_sigma_m is None:
        return None, None
    mean = np.array([[0.0, 0.0, setup.planes[n][1]] for n in names]).reshape(-1)
    angle, offset = setup.plane_angle_sigma_rad or 1e3, setup.plane_offset_sigma_m or 1e3
    return mean, np.tile([angle, angle, offset], len(names))


def _observations(
    dataset: Dataset, subset: np.ndarray, names: tuple[str, ...] | None, plane_names: tuple[str, ...] | None
) -> PlaneObservations:
    """The plane contacts at configurations ``subset`` of the elements ``names`` with the planes
    ``plane_names`` (None: those they touch, sorted; others left out)."""
    table = dataset.tables["plane_contacts"]
    index_of = dataset.config_index(table.ids["config"])
    # Only the configurations of this table: the kinematics are evaluated at each.
    subset = np.asarray(subset, dtype=int)[np.isin(subset, index_of)]
    position = {int(c): i for i, c in enumerate(subset)}
    rows = [(position[int(c)], e, p) for c, e, p in zip(index_of, table.ids["element"], table.ids["plane"],
                                                        strict=True) if int(c) in position]  # fmt: skip
    if names is None:
        names = tuple(sorted({e for _, e, _ in rows}))
        plane_names = tuple(sorted({p for _, _, p in rows}))
    index = {name: i for i, name in enumerate(names)}
    plane_index = {name: i for i, name in enumerate(plane_names)}
    rows = [r for r in rows if r[1] in index and r[2] in plane_index]
    return PlaneObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        elements=np.array([index[r[1]] for r in rows], dtype=int),
        planes=np.array([plane_index[r[2]] for r in rows], dtype=int),
        names=names,
        tips=element_tips(dataset, names),
        plane_names=plane_names,
    )
