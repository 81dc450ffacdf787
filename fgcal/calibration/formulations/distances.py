"""Distances: a ballbar (any 1D gauge) from the tool ball to fixed pivots, or between the ball
at two configurations (fgcal.factors.Distances). Unknowns besides P: the ball s (flange frame)
and the pivots a_k (W), when there are any. Scored against held-out readings by the distance,
against the truth by the ball in W, the rigid motion removed."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...core.se3 import pose
from ...data.dataset import Dataset
from ...data.truth import Truth, named_points
from ...factors import Distances, MeasurementSet, RobustLoss
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..plan_model import BallbarReadings, Planning
from ..problem import (
    Formulation,
    Keys,
    Observations,
    Problem,
    Rejection,
    Scored,
    refuse_unstarted,
    rows_of,
    subset_of,
    take,
)
from ..settings import MeasurementSettings
from ..state import Auxiliary, State

BETWEEN = "between configurations"


@dataclass(frozen=True)
class DistanceObservations(Observations):
    configs: np.ndarray  # (O,) per reading: index into config_ids
    pivots: np.ndarray  # (O,) index into names, or -1 for a reading between configurations
    others: np.ndarray  # (O,) the other configuration's index into config_ids, or -1
    distances: np.ndarray  # (O,) m
    names: tuple[str, ...]  # the pivots

    @property
    def n_residuals(self) -> int:
        return len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        pivot = self.pivots[unit]
        return str(self.config_ids[self.configs[unit]]), self.names[pivot] if pivot >= 0 else BETWEEN

    def select(self, keep: np.ndarray) -> DistanceObservations:
        return DistanceObservations(
            self.config_ids, self.q, **take(self, keep, ("configs", "pivots", "others", "distances")), names=self.names
        )


class DistanceReadings(Formulation):
    name = "distances"
    frame = "flange"
    kind = "distances"
    settings_read = ("noise.distance_sigma",)
    score = "distance"
    score_width = 1
    score_vectors = False
    likely_causes = (
        "readings that do not belong to their configurations or pivots, a ballbar's deviation from its nominal length "
        "instead of its full length, joint angles or lengths in other units than units: declares"
    )
    instrument = "ballbar"

    def planning(self, settings: MeasurementSettings) -> Planning:
        return BallbarReadings()

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.distance_m

    def gauge(self, settings: MeasurementSettings) -> str:
        return "rigid"

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        if "distances" not in dataset.tables and "tool_distances" not in dataset.tables:
            raise InputError(
                dataset.path / "dataset.yaml", "measured", "the distances formulation needs distances or tool_distances"
            )
        table = dataset.tables.get("distances")
        names = tuple(sorted({name for _, name, _ in rows_of(dataset, table, "pivot", fit)})) if table else ()
        observations = _observations(dataset, fit, None, names)
        counts = Counter(observations.pivots[observations.pivots >= 0].tolist())
        for k, name in enumerate(names):
            # Three for the pivot, three for the ball, and more for the robot.
            if counts[k] < 6:
                raise InputError(
                    dataset.path / "distances.csv",
                    "pivot",
                    f"pivot {name!r} has {counts[k]} readings in the fitting set: each pivot needs many, in clearly "
                    "different configurations",
                )
        if len(observations.configs) < 6:
            raise InputError(
                dataset.path / "dataset.yaml",
                "measured",
                f"only {len(observations.configs)} distances in the fitting set: too few to calibrate",
            )
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """A configuration's readings to the pivots the run started with, and its readings
        between two configurations (tool_distances) whose other end ``dataset`` holds (online
        recalibration adds it once both have arrived)."""
        table = dataset.tables.get("distances")
        seen = {name for _, name, _ in rows_of(dataset, table, "pivot", subset)} if table else set()
        refuse_unstarted(seen, like.names, dataset.path / "distances.csv", "pivot", "pivot",
                         "its position is not estimated")  # fmt: skip
        return _observations(dataset, subset, None, like.names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        # A reading between configurations is held out when either end is; the other end may
        # be a fitting configuration, so the observations span both sets (held-out ones first).
        observations = _observations(problem.dataset, problem.test, problem.fit, problem.observations.names)
        return (observations if len(observations.configs) else None), []

    def initial_state(self, problem: Problem) -> State:
        params = problem.robot.parameter_vector()
        ball, pivots = initial_ballbar(problem, params)
        aux = {"tool_points": Auxiliary("points", ball[None, :], ("ball",))}
        if len(pivots):  # distances between configurations alone have no fixed point
            aux["pivots"] = Auxiliary("points", pivots, problem.observations.names)
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
        pivots = state.get("pivots")
        return [
            Distances(
                kinematics,
                keys.params,
                keys["tool_points"],
                keys.aux.get("pivots"),
                0 if pivots is None else len(pivots),
                observations.configs,
                observations.pivots,
                observations.distances,
                problem.settings.noise.distance_m,
                robust=robust,
                others=observations.others,
            )
        ]

    def tool_frame(self, state: State) -> np.ndarray | None:
        return pose(np.eye(3), state.value("tool_points")[0])  # the ball's centre

    def scored(self, problem: Problem, state: State) -> Scored:
        return Scored(state.value("tool_points"), points_from="tool_points")

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        ball = np.asarray(truth.need("ballbar_ball", "ballbar.ball"))
        aux = {"tool_points": Auxiliary("points", ball[None, :], ("ball",))}
        names = problem.observations.names
        if names:
            aux["pivots"] = Auxiliary("points", named_points(truth.ballbar_pivots, names, "ballbar_pivots"), names)
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(
    dataset: Dataset, subset: np.ndarray, within: np.ndarray | None, names: tuple[str, ...]
) -> DistanceObservations:
    """Readings to the pivots ``names`` at configurations of ``subset``, and readings between
    two configurations that involve ``subset``, their other end in ``subset`` or ``within``
    (default: in ``subset`` too). The observations index ``subset`` followed by ``within``."""
    order = np.asarray(subset, dtype=int) if within is None else np.r_[subset, within].astype(int)
    rows = []
    index = {name: i for i, name in enumerate(names)}
    table = dataset.tables.get("distances")
    if table is not None:
        for i, name, values in rows_of(dataset, table, "pivot", subset):
            if name in index:
                rows.append((i, index[name], -1, float(values[0])))
    between = dataset.tables.get("tool_distances")
    if between is not None:
        config_pos = {c: i for i, c in enumerate(dataset.configs)}
        position = {int(c): i for i, c in enumerate(order)}
        for a, b, values in zip(between.ids["config_a"], between.ids["config_b"], between.values, strict=True):
            ia, ib = position.get(config_pos[a]), position.get(config_pos[b])
            if ia is not None and ib is not None and (ia < len(subset) or ib < len(subset)):
                rows.append((ia, -1, ib, float(values[0])))
    return DistanceObservations(
        **subset_of(dataset, order),
        configs=np.array([r[0] for r in rows], dtype=int),
        pivots=np.array([r[1] for r in rows], dtype=int),
        others=np.array([r[2] for r in rows], dtype=int),
        distances=np.array([r[3] for r in rows], dtype=float),
        names=names,
    )


def initial_ballbar(problem: Problem, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool ball s (flange frame) and pivots a_k (W) from the nominal model, no guess needed.

    To pivots, ``|R_j s + t_j - a_k|^2 = d^2`` is linear in s, a_k, w_k = |s|^2 + |a_k|^2 and
    M_k = a_k s^T (the bilinear term a_k . R_j s = <R_j, M_k>); that least-squares solution,
    and a start with the ball at the flange centre whose pivots a sphere fit places, are each
    refined by nonlinear least squares on (s, a) alone, with the readings between
    configurations (``|R_j s + t_j - R_b s - t_b| = d``) too, and the better kept (m). With
    readings between configurations only, the starts are the flange centre and the nominal
    tool point."""
    from scipy.optimize import least_squares

    observations = problem.observations
    flange = problem.robot.fk(observations.q, problem.robot.parameter_dict(params), tip=problem.frame)
    j, k, d, b = observations.configs, observations.pivots, observations.distances, observations.others
    R, t = flange[j, :3, :3], flange[j, :3, 3]
    R_b, t_b = flange[np.maximum(b, 0), :3, :3], flange[np.maximum(b, 0), :3, 3]
    to_pivot = k >= 0
    n_pivots = len(observations.names)
    if n_pivots:
        starts = _pivot_starts(R[to_pivot], t[to_pivot], k[to_pivot], d[to_pivot], n_pivots)
    else:
        starts = [(np.zeros(3), np.zeros((0, 3))), (problem.robot.tool_pose[:3, 3], np.zeros((0, 3)))]

    def residual(x: np.ndarray) -> np.ndarray:
        s, pivots = x[:3], x[3:].reshape(-1, 3)
        end = np.where(to_pivot[:, None], pivots[np.maximum(k, 0)] if n_pivots else 0.0, R_b @ s + t_b)
        return np.linalg.norm(R @ s + t - end, axis=1) - d

    fits = [least_squares(residual, np.concatenate([s, a.reshape(-1)]), method="lm") for s, a in starts]
    best = min(fits, key=lambda fit: fit.cost)
    if not np.all(np.isfinite(best.x)) or np.sqrt(2 * best.cost / len(d)) > 0.05:
        table = "distances.csv" if n_pivots else "tool_distances.csv"
        raise InputError(
            problem.dataset.path / table,
            None,
            "the distances cannot locate the ball and the pivots (typical residual "
            f"{np.sqrt(2 * best.cost / len(d)) * 1e3:.3g} mm with the nominal robot): measure each pivot with "
            "the tool in clearly different positions and orientations",
        )
    return best.x[:3], best.x[3:].reshape(-1, 3)


def _pivot_starts(
    R: np.ndarray, t: np.ndarray, k: np.ndarray, d: np.ndarray, n_pivots: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Starts (s, pivots) from the readings to pivots: the linear lift and the sphere fits."""
    A = np.zeros((len(k), 3 + 13 * n_pivots))
    A[:, :3] = 2.0 * np.einsum("oji,oj->oi", R, t)
    rows = np.arange(len(k))
    A[rows, 3 + 13 * k] = 1.0
    for axis in range(3):
        A[rows, 4 + 13 * k + axis] = -2.0 * t[:, axis]
    for entry in range(9):
        A[rows, 7 + 13 * k + entry] = -2.0 * R.reshape(-1, 9)[:, entry]
    linear = np.linalg.lstsq(A, d**2 - np.sum(t * t, axis=1), rcond=None)[0]
    return [
        (linear[:3], np.array([linear[4 + 13 * p : 7 + 13 * p] for p in range(n_pivots)])),
        (np.zeros(3), np.array([_sphere_centre(t[k == p], d[k == p]) for p in range(n_pivots)])),
    ]


def _sphere_centre(points: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Centre a of the sphere through points at known distances: ``2 p.a - |a|^2 = |p|^2 - d^2``
    is linear in (a, |a|^2)."""
    A = np.hstack([2.0 * points, -np.ones((len(points), 1))])
    return np.linalg.lstsq(A, np.sum(points**2, axis=1) - radii**2, rcond=None)[0][:3]
