"""Several measurement sets in one calibration (a config's ``sets:``): a composite formulation.

Each set is a registered formulation with its own settings (noise, robust losses, options). The
sets share the robot's parameters P and keep their own auxiliary unknowns, named ``SET/unknown``
(``probe/touch_points``). The composite's observations are the tuple of its sets'; its measurement
sets are theirs, each evaluated by its own kinematics (the sets may measure different tips of a
tree) on the same released parameters, and tagged with the set's index (``part``). Each member
formulation sees the problem through a view (:meth:`Combined.view`): its own settings and
observations, and the state and keys under its own names. Nothing here knows a formulation's name.

A set with ``use: validation`` is measured, never fitted: its own unknowns (a tracker's pose and
its reflectors on the flange) are registered with the robot held at the calibration, on the set's
configurations of the fitting split (on its held-out ones when the split leaves it none), and it
is scored on its held-out configurations (fgcal.calibration.formulations.registration), or on
all of them when none is held out (registered on the same rows).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gtsam
import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...data.truth import Truth
from ...factors import MeasurementSet, RobustLoss
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..problem import (
    Formulation,
    HeldOut,
    JointCovariance,
    Keys,
    Observations,
    Part,
    Prediction,
    Problem,
    Rejection,
    Scored,
    robust_scale,
)
from ..settings import MeasurementSettings
from ..state import State
from .registration import register, registered_prediction

SEP = "/"


@dataclass(frozen=True)
class Member:
    """One set of a config's sets: its name, formulation, settings and use (fit or validation)."""

    name: str
    formulation: Formulation
    settings: MeasurementSettings
    use: str = "fit"


@dataclass(frozen=True)
class SetObservations(Observations):
    """Per set its observations (None: none at these configurations). ``config_ids`` and ``q``
    are the first set's (every set's observations index the same configurations). A validation
    set's fitting observations are those its unknowns are registered on, never fitted;
    ``registered_on`` says per set on which (fit, held-out, all: nothing of it held out, scored
    on the same rows; empty for a fitting set)."""

    parts: tuple[Observations | None, ...] = ()
    fitted: tuple[bool, ...] = ()
    registered_on: tuple[str, ...] = ()

    @property
    def n_residuals(self) -> int:
        return sum(o.n_residuals for o, f in zip(self.parts, self.fitted, strict=True) if f and o is not None)

    def unit_label(self, unit: int) -> tuple[str, str]:
        raise NotImplementedError("a set's own observations label its units")

    def select(self, keep: np.ndarray) -> SetObservations:
        raise NotImplementedError("a set's own observations select their units")

    def with_part(self, index: int, observations: Observations | None) -> SetObservations:
        parts = list(self.parts)
        parts[index] = observations
        return dataclasses.replace(self, parts=tuple(parts))


def prefixed(name: str, aux: str) -> str:
    return f"{name}{SEP}{aux}"


class Combined(Formulation):
    """The formulation of a config's sets (see the module docstring)."""

    name = "sets"
    frame = "flange"
    kind = "sets"
    likely_causes = "one of the sets' (see the stage residuals of each set)"
    instrument = "sets"
    not_incremental = "online recalibration takes one formulation: calibrate each set's online"

    def __init__(self, members: list[Member]) -> None:
        self.members = tuple(members)
        fitting = [m for m in members if m.use == "fit"]
        validating = [m for m in members if m.use == "validation"]
        # The headline score: the first validation set's, else the first fitting set's.
        self.headline = members.index((validating or fitting)[0])
        self.first_fit = members.index(fitting[0])
        self.headline_name = members[self.headline].name
        head = members[self.headline].formulation
        self.unit, self.score, self.score_vectors = head.unit, head.score, head.score_vectors
        self.settings_read = tuple(sorted({o for m in members for o in m.formulation.settings_read}))

    # -- views --------------------------------------------------------------------------------

    def view(self, problem: Problem, index: int, observations: Observations | None = None) -> Problem:
        """The problem as set ``index``'s formulation sees it: its settings and (fitting) observations."""
        member = self.members[index]
        own = observations if observations is not None else problem.observations.parts[index]
        return dataclasses.replace(problem, formulation=member.formulation, settings=member.settings, observations=own)

    def own_state(self, state: State, index: int) -> State:
        """The state under set ``index``'s own names (its unknowns, unprefixed)."""
        head = prefixed(self.members[index].name, "")
        return State(state.params, {n[len(head) :]: a for n, a in state.aux.items() if n.startswith(head)})

    def own_keys(self, keys: Keys, index: int) -> Keys:
        head = prefixed(self.members[index].name, "")
        return Keys(keys.params, {n[len(head) :]: k for n, k in keys.aux.items() if n.startswith(head)})

    def own_covariance(self, covariance: JointCovariance, index: int) -> JointCovariance:
        head = prefixed(self.members[index].name, "")
        offsets = {n[len(head) :]: o for n, o in covariance.offsets.items() if n.startswith(head)}
        if "P" in covariance.offsets:
            offsets["P"] = covariance.offsets["P"]
        return JointCovariance(offsets, covariance.matrix, covariance.released)

    def parts(self, problem: Problem) -> list[Part]:
        return [
            Part(m.name, m.formulation, self.view(problem, k), m.use, k)
            for k, m in enumerate(self.members)
            if problem.observations.parts[k] is not None
        ]

    def fitting(self) -> list[int]:
        return [k for k, m in enumerate(self.members) if m.use == "fit"]

    # -- what the sets measure ------------------------------------------------------------------

    def sigma(self, settings: MeasurementSettings) -> float:
        head = self.members[self.headline]
        return head.formulation.sigma(head.settings)

    def gauge(self, settings: MeasurementSettings) -> str:
        """The gauge of the first fitting set, whose points a score against the truth measures
        (:meth:`scored`)."""
        first = self.members[self.first_fit]
        return first.formulation.gauge(first.settings)

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        return self.members[self.first_fit].formulation.frames(self.view(problem, self.first_fit))

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        raise NotImplementedError("the sets' observations need the split's held-out part: Combined.observations")

    def observations(self, dataset: Dataset, fit: np.ndarray, test: np.ndarray) -> SetObservations:
        """Each fitting set's observations of the fitting configurations; each validation set's
        of the fitting configurations if it has any there (else of the held-out ones), to
        register its own unknowns on."""
        parts, registered_on = [], []
        for k, m in enumerate(self.members):
            try:
                parts.append(m.formulation.fit_observations(dataset, m.settings, fit))
                # Nothing held out: a validation set (never fitted) is scored on the rows it is registered on.
                registered_on.append("" if m.use == "fit" else "fit" if len(test) else "all")
            except InputError as error:
                if m.use == "fit":
                    raise InputError(
                        error.source, error.field, f"set {m.name!r} (sets[{k}]): {error.message}"
                    ) from None
                try:
                    parts.append(m.formulation.fit_observations(dataset, m.settings, test))
                except InputError as again:
                    raise InputError(again.source, again.field, f"validation set {m.name!r} (sets[{k}]): "
                                     f"{again.message}") from None  # fmt: skip
                registered_on.append("held-out")
        first = parts[self.first_fit]
        return SetObservations(
            first.config_ids, first.q, tuple(parts), tuple(m.use == "fit" for m in self.members), tuple(registered_on)
        )

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        """Each set's held-out observations; a validation set with none held out (holdout 0, or
        none of its configurations in the held-out split) is scored on all its own, the rows its
        unknowns are registered on (never fitted: held out from the calibration all the same)."""
        fit = problem.observations
        parts, flagged, registered_on = [], [], list(fit.registered_on)
        for k, m in enumerate(self.members):
            view = self.view(problem, k)
            own = self.own_state(state, k) if m.use == "fit" else register(view, state.params)
            observations, rejected = m.formulation.test_observations(view, own)
            if observations is None and m.use == "validation" and fit.parts[k] is not None:
                observations, rejected, registered_on[k] = fit.parts[k], [], "all"
            parts.append(observations)
            flagged += rejected
        if all(p is None for p in parts):
            return None, flagged
        first = next(p for p in parts if p is not None)
        return dataclasses.replace(
            fit, config_ids=first.config_ids, q=first.q, parts=tuple(parts), registered_on=tuple(registered_on)
        ), flagged

    def initial_state(self, problem: Problem) -> State:
        params, aux = None, {}
        for k in self.fitting():
            own = self.members[k].formulation.initial_state(self.view(problem, k))
            params = own.params if params is None else params
            aux.update({prefixed(self.members[k].name, n): a for n, a in own.aux.items()})
        return State(params, aux)

    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: tuple[RobustLoss | None, ...] | None,
    ) -> list[MeasurementSet]:
        """Each fitting set's measurement sets, on its own kinematics (the released parameters of
        ``kinematics``), tagged with the set's index."""
        out = []
        for k in self.fitting():
            own = observations.parts[k]
            if own is None:
                continue
            view = self.view(problem, k, own)
            own_kinematics = view.kinematics(State(kinematics.base), kinematics.released, own)
            loss = robust[k] if robust is not None else None
            sets = self.members[k].formulation.measurement_sets(
                view, own, own_kinematics, self.own_keys(keys, k), self.own_state(state, k), loss
            )
            for s in sets:
                s.part = k
            # A set on P alone while nothing is released (stage 0 of the others' unknowns) has no variable.
            out += [s for s in sets if s.variables]
        return out

    def robust_loss(self, problem: Problem, measurements: list[MeasurementSet], values: gtsam.Values):
        """Per set its own loss, its threshold in its own robust scale; the scales per set."""
        losses, scales = [None] * len(self.members), []
        for part in self.parts(problem):
            if part.use != "fit":
                continue
            own = part.formulation.robust_loss(part.problem, part.sets_of(measurements), values)
            if own is not None:
                losses[part.index] = own[0]
                scales.append(own[1])
        return (tuple(losses), tuple(scales)) if scales else None

    def reject(
        self, problem: Problem, sets: list[MeasurementSet], values: gtsam.Values, scale: float
    ) -> tuple[Observations, list[Rejection]] | None:
        """Each fitting set's gross errors, in its own robust units and scale."""
        observations, records = problem.observations, []
        for part in self.parts(problem):
            if part.use != "fit":
                continue
            own = part.sets_of(sets)
            if not own:
                continue
            outcome = part.formulation.reject(part.problem, own, values, robust_scale(own, values))
            if outcome is not None:
                observations = observations.with_part(part.index, outcome[0])
                records += outcome[1]
        return (observations, records) if records else None

    # -- held-out scores ---------------------------------------------------------------------------

    def set_state(self, problem: Problem, state: State, index: int) -> State:
        """A set's own state: a fitting set's from the calibration, a validation set's registered."""
        if self.members[index].use == "fit":
            return self.own_state(state, index)
        return register(self.view(problem, index), state.params)

    def held_out_errors(self, problem: Problem, observations: Observations, state: State) -> dict[str, HeldOut]:
        """Each set's scores, keyed ``SET/score``; the headline set's also under its own keys."""
        out = {}
        for k, m in enumerate(self.members):
            own = observations.parts[k]
            if own is None:
                continue
            errors = m.formulation.held_out_errors(self.view(problem, k), own, self.set_state(problem, state, k))
            out.update({prefixed(m.name, key): e for key, e in errors.items()})
            if k == self.headline:
                out.update(errors)
        return out

    def predicted_held_out(
        self, problem: Problem, observations: Observations, state: State, covariance: JointCovariance, factor: float
    ) -> Prediction | None:
        return self.set_prediction(problem, observations, state, covariance, factor, self.headline)

    def set_prediction(
        self,
        problem: Problem,
        observations: Observations,
        state: State,
        covariance: JointCovariance,
        factor: float,
        index: int,
    ) -> Prediction | None:
        """The predicted RMS of set ``index``'s main held-out score: a fitting set's as its
        formulation predicts it; a validation set's through its registration."""
        own = observations.parts[index]
        if own is None:
            return None
        view, member = self.view(problem, index), self.members[index]
        if member.use == "fit":
            return member.formulation.predicted_held_out(
                view, own, self.own_state(state, index), self.own_covariance(covariance, index), factor
            )
        same = observations.registered_on[index] in ("held-out", "all")
        return registered_prediction(view, own, register(view, state.params), covariance, factor, same)

    # -- against a simulation's truth, and what the calibration hands on ------------------------------

    def scored(self, problem: Problem, state: State) -> Scored:
        """The first fitting set's scored points, its unknowns' names prefixed."""
        k = self.first_fit
        own = self.members[k].formulation.scored(self.view(problem, k), self.own_state(state, k))
        name = self.members[k].name
        return dataclasses.replace(
            own,
            points_from=None if own.points_from is None else prefixed(name, own.points_from),
            instrument_from=None if own.instrument_from is None else prefixed(name, own.instrument_from),
        )

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot, params, aux = None, None, {}
        for k in self.fitting():
            own_robot, own = self.members[k].formulation.true_state(self.view(problem, k), truth)
            robot, params = (own_robot, own.params) if robot is None else (robot, params)
            aux.update({prefixed(self.members[k].name, n): a for n, a in own.aux.items()})
        return robot, State(params, aux)

    def tool_frame(self, state: State) -> np.ndarray | None:
        return self.members[self.first_fit].formulation.tool_frame(self.own_state(state, self.first_fit))

    def details(self, problem: Problem) -> dict:
        out = {}
        for part in self.parts(problem):
            own = part.formulation.details(part.problem)
            if own:
                out[part.name] = own
        return {"sets_details": out} if out else {}
