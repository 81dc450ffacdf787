"""What the contact formulations share (self_contact, planes): the contact elements (balls on
tips of a tree, dataset.yaml contact), their unknowns (centres on their tips and radii, with the
drawing's priors), the tips the kinematics give, and the score against a simulation's truth
(the balls' centres, carried to W, the rigid motion removed)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from ...core.errors import InputError
from ...data.dataset import ContactSetup, Dataset
from ...data.truth import FILE, Truth
from ..problem import Problem, Scored
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
