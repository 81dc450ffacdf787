"""Touch points: a probe on the flange seated in fixed sockets at many configurations, and known
distances between sockets for the scale (fgcal.factors.TouchPoints, SocketSpacings). Unknowns
besides P: the probe s (flange frame) and the sockets a_k (W). Scored against the truth by the
probe in W, the rigid motion removed (W is where the nominal base puts the robot)."""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...core.se3 import pose, transform_points
from ...data.dataset import Dataset
from ...data.truth import Truth, named_points
from ...factors import MeasurementSet, RobustLoss, SocketSpacings, TouchPoints
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..plan_model import Planning, ProbeTouches
from ..prediction import scored_jacobian
from ..problem import (
    Formulation,
    HeldOut,
    JointCovariance,
    Keys,
    Observations,
    Problem,
    Rejection,
    Scored,
    measured_table,
    refuse_unstarted,
    rows_of,
    subset_of,
    take,
)
from ..settings import MeasurementSettings
from ..state import Auxiliary, State


@dataclass(frozen=True)
class TouchObservations(Observations):
    configs: np.ndarray  # (O,) per touch: index into config_ids
    sockets: np.ndarray  # (O,) index into names
    names: tuple[str, ...]  # the sockets
    spacings: np.ndarray  # (S, 2) socket indices with a known distance
    spacing_m: np.ndarray  # (S,)
    # Sockets only held-out configurations touch (a validation set's): (name, configurations).
    test_points: tuple[tuple[str, np.ndarray], ...] = ()

    @property
    def n_residuals(self) -> int:
        return 3 * len(self.configs) + len(self.spacing_m)

    def unit_label(self, unit: int) -> tuple[str, str]:
        return str(self.config_ids[self.configs[unit]]), self.names[self.sockets[unit]]

    def select(self, keep: np.ndarray) -> TouchObservations:
        return TouchObservations(
            self.config_ids, self.q, **take(self, keep, ("configs", "sockets")), names=self.names,
            spacings=self.spacings, spacing_m=self.spacing_m,
        )  # fmt: skip


class Touch(Formulation):
    name = "touch"
    frame = "flange"
    kind = "touch_points"
    settings_read = ("noise.touch_sigma", "noise.spacing_sigma")
    likely_causes = (
        "touch rows naming the wrong point, joint angles in other units than units: declares, or another robot than "
        "the one that moved"
    )
    instrument = "touch"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.touch_m

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def planning(self, settings: MeasurementSettings) -> Planning:
        return ProbeTouches()

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        table = measured_table(dataset, "touch_points", self.name)
        # The sockets the fit touches (one only a validation set touches is not estimated).
        names = tuple(sorted({name for _, name, _ in rows_of(dataset, table, "point", fit)}))
        observations = _observations(dataset, fit, names)
        if not len(observations.configs):
            raise InputError(dataset.path / "touch_points.csv", None, "no touch in the fitting set")
        # A point touched once only locates itself: it says nothing about the robot.
        counts = Counter(observations.sockets.tolist())
        for k, name in enumerate(names):
            if counts.get(k, 0) < 2:
                raise InputError(
                    dataset.path / "touch_points.csv",
                    "point",
                    f"point {name!r} is touched {counts.get(k, 0)} times in the fitting set: "
                    "each point needs several touches in different configurations",
                )
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's touches of the points the run started with; the known spacings
        between points (point_distances) are no configuration's: folded in once (online_once)."""
        seen = {name for _, name, _ in rows_of(dataset, measured_table(dataset, "touch_points", self.name), "point",
                                                 subset)}  # fmt: skip
        refuse_unstarted(seen, like.names, dataset.path / "touch_points.csv", "point", "point",
                         "its position is not estimated")  # fmt: skip
        return _observations(dataset, subset, like.names, spacings=False)

    def online_once(self, problem: Problem) -> Observations | None:
        """The known spacings between the points the run started with (point_distances)."""
        observations = _observations(problem.dataset, np.zeros(0, dtype=int), problem.observations.names)
        return observations if len(observations.spacing_m) else None

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        dataset, names = problem.dataset, problem.observations.names
        observations = _observations(dataset, problem.test, names, spacings=False)
        others: dict[str, list[int]] = {}
        for i, name, _ in rows_of(dataset, dataset.tables["touch_points"], "point", problem.test):
            if name not in names:
                others.setdefault(name, []).append(i)
        for name, configs in others.items():
            if len(configs) < 2:
                raise InputError(
                    problem.settings.source,
                    "validation",
                    f"socket {name!r} is touched once, at held-out configuration "
                    f"{observations.config_ids[configs[0]]}, and never in the fitting set: touch it at several "
                    "configurations to score it (at each touch, against its position from the others)",
                )
        test_points = tuple((name, np.array(configs)) for name, configs in sorted(others.items()))
        observations = dataclasses.replace(observations, test_points=test_points)
        return (observations if len(observations.configs) or test_points else None), []

    def initial_state(self, problem: Problem) -> State:
        params = problem.robot.parameter_vector()
        probe, sockets = initial_touch(problem, params)
        names = problem.observations.names
        return State(
            params,
            {
                "tool_points": Auxiliary("points", probe[None, :], ("probe",)),
                "touch_points": Auxiliary("points", sockets, names),
            },
        )

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
        n_sockets = len(state.value("touch_points"))
        sets: list[MeasurementSet] = []
        if len(observations.configs):  # none: the spacings alone (online_once)
            sets.append(
                TouchPoints(
                    kinematics,
                    keys.params,
                    keys["tool_points"],
                    keys["touch_points"],
                    n_sockets,
                    observations.configs,
                    observations.sockets,
                    noise.touch_m,
                    robust=robust,
                )
            )
        if len(observations.spacing_m):
            sets.append(
                SocketSpacings(
                    keys["touch_points"], n_sockets, observations.spacings, observations.spacing_m, noise.spacing_m
                )
            )
        return sets

    def held_out_errors(self, problem: Problem, observations: Observations, state: State) -> dict[str, HeldOut]:
        """At each held-out touch, the probe against its socket's estimate; at a touch of a
        socket the fit never saw, against the socket where the socket's other held-out
        touches put it (leave one out: how the robot moves the probe, not where the socket is)."""
        errors, configs = [], []
        if len(observations.configs):
            known = super().held_out_errors(problem, observations, state)["tool_point"]
            errors.append(known.errors)
            configs.append(known.configs)
        for _, at in observations.test_points:
            motion = problem.dataset.motion_of(observations.config_ids[at])
            flange = problem.robot.fk(
                observations.q[at], problem.robot.parameter_dict(state.params), motion, tip=problem.frame
            )
            probe = transform_points(flange, state.value("tool_points")[0])
            errors.append(probe - (probe.sum(axis=0) - probe) / (len(at) - 1))
            configs.append(at)
        return {"tool_point": HeldOut(np.concatenate(errors), np.concatenate(configs))} if errors else {}

    def held_out_variances(
        self, problem: Problem, observations: Observations, state: State, covariance: JointCovariance, factor: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Known sockets as the main set says; a leave-one-out touch's error A_j - mean_{i != j} A_i
        through P and the probe (A: the probe's position's Jacobian), its noise
        3 sigma^2 (1 + 1/(n - 1))."""
        parameters, noise = [], []
        if len(observations.configs):
            p, n = super().held_out_variances(problem, observations, state, covariance, factor)
            parameters.append(p)
            noise.append(n)
        if observations.test_points:
            scored = self.scored(problem, state)
            sigma2 = 3.0 * factor * problem.settings.noise.touch_m**2
            for _, at in observations.test_points:
                motion = problem.dataset.motion_of(observations.config_ids[at])
                J, names = scored_jacobian(problem, state, scored, covariance.released, observations.q[at], motion)
                loo = J - (J.sum(axis=0) - J) / (len(at) - 1)
                parameters.append(np.einsum("oij,jk,oik->o", loo, covariance.block(names), loo))
                noise.append(np.full(len(at), sigma2 * (1 + 1 / (len(at) - 1))))
        if not parameters:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(parameters), np.concatenate(noise)

    def test_point_modes(self, problem: Problem, observations: Observations) -> dict[str, str]:
        return {name: "leave-one-out" for name, _ in observations.test_points}

    def tool_frame(self, state: State) -> np.ndarray | None:
        return pose(np.eye(3), state.value("tool_points")[0])  # the probe's centre

    def scored(self, problem: Problem, state: State) -> Scored:
        return Scored(state.value("tool_points"), points_from="tool_points")

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        names = problem.observations.names
        probe = np.asarray(truth.need("touch_probe", "touch_probe"))
        aux = {
            "tool_points": Auxiliary("points", probe[None, :], ("probe",)),
            "touch_points": Auxiliary("points", named_points(truth.touch_points, names, "touch_points"), names),
        }
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(dataset: Dataset, subset: np.ndarray, names: tuple[str, ...], spacings: bool = True):
    """The touches of ``subset`` on the sockets ``names`` (others left out), and the known
    spacings between them."""
    index = {name: i for i, name in enumerate(names)}
    rows = [(i, index[name]) for i, name, _ in rows_of(dataset, dataset.tables["touch_points"], "point", subset)
            if name in index]  # fmt: skip
    pairs, distances = [], []
    table = dataset.tables.get("point_distances")
    if spacings and table is not None:
        for a, b, d in zip(table.ids["point_a"], table.ids["point_b"], table.values[:, 0], strict=True):
            if a in index and b in index:
                pairs.append((index[a], index[b]))
                distances.append(float(d))
    return TouchObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        sockets=np.array([r[1] for r in rows], dtype=int),
        names=names,
        spacings=np.array(pairs, dtype=int).reshape(-1, 2),
        spacing_m=np.array(distances, dtype=float),
    )


def initial_touch(problem: Problem, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Touch probe s (flange frame) and touch points a_k (W) from the nominal model, no guess
    needed: ``R_j s - a_k = -p_j`` is linear in both, solved by least squares (m)."""
    observations = problem.observations
    flange = problem.robot.fk(observations.q, problem.robot.parameter_dict(params), tip=problem.frame)
    n_points = len(observations.names)
    n_touches = len(observations.configs)
    A = np.zeros((3 * n_touches, 3 + 3 * n_points))
    b = np.zeros(3 * n_touches)
    for row, (j, k) in enumerate(zip(observations.configs, observations.sockets, strict=True)):
        A[3 * row : 3 * row + 3, :3] = flange[j, :3, :3]
        A[3 * row : 3 * row + 3, 3 + 3 * k : 6 + 3 * k] = -np.eye(3)
        b[3 * row : 3 * row + 3] = -flange[j, :3, 3]
    solution, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
    if rank < A.shape[1]:
        raise InputError(
            problem.dataset.path / "touch_points.csv",
            None,
            "the touches cannot locate the probe: touch each point with the tool in clearly different orientations",
        )
    return solution[:3], solution[3:].reshape(n_points, 3)
