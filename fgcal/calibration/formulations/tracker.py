"""The classical formulation (SPEC section 4, eq. 1): a laser tracker measures reflectors on the
tool, ``m = L X(P, q) s_t``. Unknowns besides P: the tracker's pose L = T_T_W and the
reflectors s_t (flange frame). Scored in the tracker's frame, which the data fix: no gauge.

A separate validation set may measure a reflector the fit never saw (a test point): it is
scored at its declared position on the flange (config ``validation.tool_points``), carried by
the best rigid motion of the declared fitting reflectors onto their estimates, or else at its
leave-one-out position (the mean of its other measurements carried back to the flange).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...core.se3 import inverse, kabsch, transform_points
from ...data.dataset import Dataset
from ...data.truth import Truth, named_points
from ...factors import MeasurementSet, RobustLoss, TrackerPoints, point_jacobian
from ...model.robot import Robot
from ..batch import BatchKinematics
from ..plan_model import Planning, Reflectors
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
class TrackerObservations(Observations):
    configs: np.ndarray  # (O,) per point: index into config_ids
    targets: np.ndarray  # (O,) index into names
    measured: np.ndarray  # (O, 3) m, tracker frame
    names: tuple[str, ...]  # the reflectors the fit estimates
    tips: tuple[str, ...] = ()  # per name, the frame it is fixed to (a tree's tip; empty: the flange)
    # Reflectors only a validation set measured: (name, configurations, measured points).
    test_points: tuple[tuple[str, np.ndarray, np.ndarray], ...] = ()

    @property
    def n_residuals(self) -> int:
        return 3 * len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        return str(self.config_ids[self.configs[unit]]), self.names[self.targets[unit]]

    def select(self, keep: np.ndarray) -> TrackerObservations:
        return TrackerObservations(
            self.config_ids,
            self.q,
            **take(self, keep, ("configs", "targets", "measured")),
            names=self.names,
            tips=self.tips,
        )

    def frame_rows(self, frames: str | tuple[str, ...]) -> np.ndarray:
        """Per point, its row among the kinematics' poses of ``frames`` (frame-major)."""
        if isinstance(frames, str):
            return self.configs
        tip = np.array([frames.index(t) for t in self.tips], dtype=int)
        return tip[self.targets] * len(self.q) + self.configs


class Tracker(Formulation):
    name = "tracker"
    frame = "flange"
    kind = "tracker_points"
    settings_read = ("noise.tracker_sigma",)
    rejection_name = "target"
    likely_causes = (
        "the tracker points do not belong to their configurations (rows shifted, configuration ids mismatched), "
        "reflector names swapped between targets, joint angles or lengths in other units than units: declares, or "
        "another robot than the one that moved"
    )
    instrument = "tracker"

    def sigma(self, settings: MeasurementSettings) -> float:
        return settings.noise.tracker_m

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        """The flange, or the tips of a tree the reflectors are on (dataset.yaml tracker.tips and
        tip), those of the test points a validation set measures among them."""
        tips = {
            target_tip(problem.dataset, name) for name in set(problem.dataset.tables["tracker_points"].ids["target"])
        }
        if tips == {problem.robot.flange_name}:
            return self.frame
        return tuple(t for t in problem.robot.tip_names if t in tips)

    def planning(self, settings: MeasurementSettings) -> Planning:
        return Reflectors()

    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        rows = list(rows_of(dataset, measured_table(dataset, "tracker_points", self.name), "target", fit))
        # The reflectors the fit sees; one measured only at held-out configurations (a test point
        # of a validation set) is scored through its declared or leave-one-out position.
        names = tuple(sorted({name for _, name, _ in rows}))
        observations = _observations(dataset, fit, rows, names)
        if len(rows) < 3 * len(names) + 2:
            raise InputError(
                dataset.path / "tracker_points.csv",
                None,
                f"only {len(rows)} tracker measurements in the fitting set: too few",
            )
        return observations

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        rows = list(rows_of(dataset, measured_table(dataset, "tracker_points", self.name), "target", subset))
        refuse_unstarted((name for _, name, _ in rows), like.names, dataset.path / "tracker_points.csv", "target",
                         "reflector", "its position on the flange is not estimated")  # fmt: skip
        return _observations(dataset, subset, rows, like.names)

    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        dataset = problem.dataset
        rows = list(rows_of(dataset, dataset.tables["tracker_points"], "target", problem.test))
        if not rows:
            return None, []
        names = problem.observations.names
        known = [row for row in rows if row[1] in names]
        observations = _observations(dataset, problem.test, known, names)
        test_points = []
        for target in sorted({name for _, name, _ in rows} - set(names)):
            mine = [(i, xyz) for i, name, xyz in rows if name == target]
            test_points.append((target, np.array([i for i, _ in mine]), np.array([xyz for _, xyz in mine])))
        return TrackerObservations(**{**observations.__dict__, "test_points": tuple(test_points)}), []

    def initial_state(self, problem: Problem) -> State:
        observations = problem.observations
        T_L, points = initial_tracker(problem.robot, problem.robot.parameter_vector(), observations)
        return State(
            problem.robot.parameter_vector(),
            {"tracker": Auxiliary("pose3", T_L), "tool_points": Auxiliary("points", points, observations.names)},
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
        return [
            TrackerPoints(
                kinematics,
                keys.params,
                keys["tracker"],
                keys["tool_points"],
                len(state.value("tool_points")),
                observations.frame_rows(problem.frame),
                observations.targets,
                observations.measured,
                problem.settings.noise.tracker_m,
                robust=robust,
            )
        ]

    def held_out_errors(self, problem: Problem, observations: Observations, state: State) -> dict[str, HeldOut]:
        errors, configs = [], []
        if len(observations.configs):
            known = super().held_out_errors(problem, observations, state)["tool_point"]
            errors.append(known.errors)
            configs.append(known.configs)
        for target, at, measured in observations.test_points:
            motion = problem.dataset.motion_of(observations.config_ids[at])
            tip = target_tip(problem.dataset, target)
            errors.append(_test_point_errors(problem, state, target, observations.q[at], motion, measured, tip))
            configs.append(at)
        if not errors:
            return {}
        return {"tool_point": HeldOut(np.concatenate(errors), np.concatenate(configs))}

    def held_out_variances(
        self, problem: Problem, observations: Observations, state: State, covariance: JointCovariance, factor: float
    ) -> tuple[np.ndarray, np.ndarray]:
        parameters, noise = [], []
        if len(observations.configs):
            p, n = super().held_out_variances(problem, observations, state, covariance, factor)
            parameters.append(p)
            noise.append(n)
        for p, n in _test_point_variances(problem, observations, state, covariance, factor):
            parameters.append(p)
            noise.append(n)
        if not parameters:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(parameters), np.concatenate(noise)

    def test_point_modes(self, problem: Problem, observations: Observations) -> dict[str, str]:
        declared = problem.settings.validation_tool_points
        return {name: "declared" if name in declared else "leave-one-out" for name, _, _ in observations.test_points}

    def scored(self, problem: Problem, state: State) -> Scored:
        frames, tips = problem.frame, problem.observations.tips
        on = None if isinstance(frames, str) else np.array([frames.index(t) for t in tips], dtype=int)
        return Scored(state.value("tool_points"), state.value("tracker"), "tool_points", "tracker", tips=on)

    def unit_tips(self, problem: Problem, observations: Observations) -> np.ndarray | None:
        if isinstance(problem.frame, str):
            return None
        return np.array(observations.tips, dtype=object)[observations.targets]

    def score_configs(self, main: MeasurementSet) -> np.ndarray:
        return np.asarray(main.configs) % len(main.kinematics.q)

    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        robot = problem.dataset.robot.with_model(truth.model)
        names = problem.observations.names
        aux = {
            "tracker": Auxiliary("pose3", inverse(truth.tracker_pose)),
            "tool_points": Auxiliary("points", named_points(truth.tracker_targets, names, "tracker_targets"), names),
        }
        return robot, State(robot.parameter_vector(truth.parameters), aux)


def _observations(dataset: Dataset, subset: np.ndarray, rows: list, names: tuple[str, ...]) -> TrackerObservations:
    index = {name: i for i, name in enumerate(names)}
    return TrackerObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        targets=np.array([index[r[1]] for r in rows], dtype=int),
        measured=np.array([r[2] for r in rows], dtype=float).reshape(-1, 3),
        names=names,
        tips=tuple(target_tip(dataset, name) for name in names),
    )


def target_tip(dataset: Dataset, name: str) -> str:
    """The tip a tracker target is on: dataset.yaml tracker.tips, else tip, else the flange."""
    return dataset.target_tips.get(name, dataset.tip or dataset.robot.flange_name)


# -- starting values ------------------------------------------------------------------------


def initial_tracker(
    robot: Robot, params: np.ndarray, observations: TrackerObservations, rounds: int = 15
) -> tuple[np.ndarray, np.ndarray]:
    """Tracker pose T_T_W and tool points from the nominal model, no guess needed:
    alternate a Kabsch fit of the tracker pose with a linear fit of the tool points and the
    tracker's position, from several starting orientations of the tracker (the 24 rotations
    of a cube, and the Kabsch fit of the flange origins), keeping the best fit. One start is
    not enough: when the flange origin barely moves (a positioner's table centre on its
    axes) the flange origins say nothing about the tracker's orientation, and the alternation
    from a wrong one settles in a false minimum half a metre off."""
    j, t, measured = observations.configs, observations.targets, observations.measured
    values = robot.parameter_dict(params)
    tips = observations.tips or (robot.flange_name,) * len(observations.names)
    poses = {tip: robot.fk(observations.q, values, tip=tip) for tip in set(tips)}
    T_obs = np.stack([poses[tips[target]][config] for config, target in zip(j, t, strict=True)])
    n_targets = len(observations.names)
    R_j, p_j = T_obs[:, :3, :3], T_obs[:, :3, 3]
    # m - R_L p_j = R_L R_j s_t + t_L is linear in the tool points and t_L. Turned by R_L^T,
    # each observation's rows keep their norm: R_L^T m - p_j = R_j s_t + u, with u = R_L^T t_L,
    # whose matrix does not depend on R_L: one pseudo-inverse serves every start and round.
    A = np.zeros((len(j), 3, 3 * n_targets + 3))
    for target in range(n_targets):
        A[t == target, :, 3 * target : 3 * target + 3] = R_j[t == target]
    A[:, :, -3:] = np.eye(3)
    solve = pseudo_inverse(A.reshape(-1, A.shape[2]))

    def fit_points(R_L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        solution = solve @ (measured @ R_L - p_j).reshape(-1)
        return solution[:-3].reshape(n_targets, 3), R_L @ solution[-3:]

    def refine(R_L: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        for _ in range(rounds):
            points, t_L = fit_points(R_L)
            R_L, t_L = kabsch(transform_points(T_obs, points[t]), measured)
        points, t_L = fit_points(R_L)
        world = np.einsum("oij,oj->oi", R_j, points[t]) + p_j
        cost = float(np.sum((world @ R_L.T + t_L - measured) ** 2))
        return cost, R_L, t_L, points

    starts = [kabsch(p_j, measured)[0], *cube_rotations()]
    _, R_L, t_L, points = min((refine(R) for R in starts), key=lambda fit: fit[0])
    T_L = np.eye(4)
    T_L[:3, :3], T_L[:3, 3] = R_L, t_L
    return T_L, points


def pseudo_inverse(A: np.ndarray) -> np.ndarray:
    """The minimum-norm least-squares solver of A x = b as a matrix, with np.linalg.lstsq's
    cutoff of small singular values (machine epsilon times the larger dimension)."""
    U, singular, Vt = np.linalg.svd(A, full_matrices=False)
    kept = singular > np.finfo(float).eps * max(A.shape) * singular[0]
    return Vt[kept].T @ (U[:, kept].T / singular[kept, None])


def cube_rotations() -> list[np.ndarray]:
    """The 24 proper rotations that map the coordinate axes onto themselves."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            R[np.arange(3), perm] = signs
            if np.linalg.det(R) > 0:
                out.append(R)
    return out


# -- test points of a validation set --------------------------------------------------------------


def declared_test_point(problem: Problem, state: State, target: str) -> np.ndarray | None:
    """A declared test point in the calibrated flange frame, or None. Declared positions are
    in the tool's drawing; when three or more fitting targets are declared too, the drawing is
    carried onto their estimates by the best rigid motion (the calibrated flange frame is an
    effective one: the last joint's errors move it, and the fitted targets with it), else the
    declared position is taken as it is."""
    declared = problem.settings.validation_tool_points
    if target not in declared:
        return None
    names = problem.observations.names
    anchors = [t for t in names if t in declared]
    point = np.array(declared[target], dtype=float)
    if len(anchors) < 3:
        return point
    R, t = kabsch(
        np.array([declared[a] for a in anchors]), state.value("tool_points")[[names.index(a) for a in anchors]]
    )
    return R @ point + t


def _test_point_errors(
    problem: Problem, state: State, target: str, q: np.ndarray, motion: np.ndarray, measured: np.ndarray, tip: str
) -> np.ndarray:
    """Error vectors (m, tracker frame) at a tool point the fit never saw, measured at ``q``:
    at its declared position, else at its leave-one-out position (its position is then not
    scored, only how the robot moves it)."""
    T_T_n = state.value("tracker") @ problem.robot.fk(q, problem.robot.parameter_dict(state.params), motion, tip=tip)
    declared = declared_test_point(problem, state, target)
    if declared is not None:
        return transform_points(T_T_n, declared) - measured
    if len(q) < 2:
        raise InputError(
            problem.settings.source,
            "validation.tool_points",
            f"test point {target!r} is measured once in the validation set: declare its position on the flange, "
            "or measure it at several configurations (it is fitted leave-one-out)",
        )
    back = back_projections(T_T_n, measured)
    loo = (back.sum(axis=0) - back) / (len(q) - 1)
    return np.einsum("oij,oj->oi", T_T_n[:, :3, :3], loo) + T_T_n[:, :3, 3] - measured


def _test_point_variances(
    problem: Problem, observations: TrackerObservations, state: State, covariance: JointCovariance, factor: float
):
    """Per test point, the variance each of its held-out errors takes from P and the tracker
    pose, and its noise variance. Declared: the error's Jacobian A_j at the declared point.
    Leave-one-out: ``A_j - R_j mean_{i != j}(R_i^T A_i)`` (the refitted point follows the
    others), and the noise 3 sigma^2 (1 + 1/(n - 1))."""
    if not observations.test_points:
        return
    model = problem.kinematics(state, covariance.released, observations)
    p_values = model.base[model.index]
    T_X, J_P = model.poses(p_values), model.jacobians(p_values)
    T_L = state.value("tracker")
    block = covariance.block(["P", "tracker"])
    sigma2 = 3.0 * factor * problem.settings.noise.tracker_m**2
    frames = problem.frame
    for target, at, measured in observations.test_points:
        # Its tip's rows among the kinematics' (frame-major on a tree).
        rows = at if isinstance(frames, str) else frames.index(target_tip(problem.dataset, target)) * len(model.q) + at
        declared = declared_test_point(problem, state, target)
        # Where the point is on the flange: declared, or as the measurements put it (for A_j only).
        s = declared if declared is not None else back_projections(T_L @ T_X[rows], measured).mean(axis=0)
        R_X = T_X[rows, :3, :3]
        p_W = np.einsum("oij,j->oi", R_X, s) + T_X[rows, :3, 3]
        A = np.concatenate(
            [T_L[:3, :3] @ point_jacobian(R_X, np.broadcast_to(s, (len(at), 3))) @ J_P[rows],
             np.broadcast_to(point_jacobian(T_L[:3, :3], p_W), (len(at), 3, 6))],
            axis=2,
        )  # fmt: skip
        if declared is not None:
            yield np.einsum("oij,jk,oik->o", A, block, A), np.full(len(at), sigma2)
            continue
        R = T_L[:3, :3] @ R_X
        back = np.einsum("oji,ojk->oik", R, A)  # R_i^T A_i
        loo = A - np.einsum("oij,ojk->oik", R, (back.sum(axis=0) - back) / (len(at) - 1))
        yield np.einsum("oij,jk,oik->o", loo, block, loo), np.full(len(at), sigma2 * (1 + 1 / (len(at) - 1)))


def back_projections(T_T_n: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Measured points (tracker frame) carried back into the flange frame of each pose T_T_n."""
    return np.einsum("oji,oj->oi", T_T_n[:, :3, :3], measured - T_T_n[:, :3, 3])
