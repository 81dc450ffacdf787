"""Scored points: where the points a score against the truth measures are (fgcal.calibration.
problem.Scored, ``p = L X(q) s_t``), how well the estimate knows them (the joint covariance of
the parameters and auxiliary unknowns carried through the tracker-point model, the score's
gauge removed), and the workspace map of the report. The model is the tracker's measurement
model (fgcal.factors.TrackerPoints) with L and S variables or constants: written once.
Configurations come with their motion features (fgcal.model.motion; None: no history), which the
model needs as much as the joint values."""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from ..factors import TrackerPoints
from ..model.robot import Robot
from .batch import BatchKinematics
from .blind_spots import BlindSpot, blind_spots
from .gauge import without_gauge
from .problem import JointCovariance, Prediction, Problem, Scored
from .state import State

_P, _L, _S = (gtsam.symbol("p", 0), gtsam.symbol("l", 0), gtsam.symbol("s", 0))


def _model(kinematics: BatchKinematics, scored: Scored, n_configs: int, variables: Sequence[str] = ()) -> TrackerPoints:
    """The scored points at every configuration (point-major: point t at all configurations,
    then the next), with L and S variables where ``variables`` names them."""
    k = len(scored.points)
    tracker = scored.instrument if scored.instrument is not None else np.eye(4)
    tips = np.zeros(k, dtype=int) if scored.tips is None else np.asarray(scored.tips, dtype=int)
    return TrackerPoints(
        kinematics,
        _P if kinematics.n_released else None,
        _L if "instrument" in variables else None,
        _S if "points" in variables else None,
        k,
        (tips[:, None] * n_configs + np.arange(n_configs)[None, :]).reshape(-1),  # frame-major rows
        np.repeat(np.arange(k), n_configs),
        np.zeros((k * n_configs, 3)),
        1.0,
        tracker=None if "instrument" in variables else tracker,
        points=None if "points" in variables else scored.points,
    )


def scored_positions(
    robot: Robot,
    frame: str | tuple[str, ...],
    params: np.ndarray,
    q: np.ndarray,
    motion: np.ndarray | None,
    scored: Scored,
) -> np.ndarray:
    """The scored points (k * N, 3) at configurations q, point-major, in the score's frame."""
    model = _model(BatchKinematics(robot, params, [], q, frame, motion), scored, len(q))
    return model.compute([], False).residual.reshape(-1, 3)


def scored_jacobian(
    problem: Problem, state: State, scored: Scored, released: Sequence[str], q: np.ndarray, motion: np.ndarray | None
) -> tuple[np.ndarray, list[str]]:
    """Jacobian (k * N, 3, m) of the scored points through P (``released``), the instrument and
    the points where they are unknowns, and the names of those unknowns in column order."""
    kinematics = BatchKinematics(problem.robot, state.params, released, q, problem.frame, motion)
    variables = []
    names = ["P"] if released else []
    inputs: list = [kinematics.base[kinematics.index]] if released else []
    if scored.instrument_from is not None:
        variables.append("instrument")
        names.append(scored.instrument_from)
        inputs.append(gtsam.Pose3(scored.instrument))
    if scored.points_from is not None:
        variables.append("points")
        names.append(scored.points_from)
        inputs.append(np.asarray(scored.points, dtype=float).reshape(-1))
    model = _model(kinematics, scored, len(q), variables)
    blocks = model.compute(inputs, True).blocks
    if scored.points_from is not None and state.aux[scored.points_from].kind == "pose3":
        # The point is the origin of a pose E: it moves by R_E v under E Exp([w, v]).
        R_E = state.value(scored.points_from)[:3, :3]
        blocks[-1] = np.hstack([np.zeros((len(blocks[-1]), 3)), blocks[-1] @ R_E])
    return np.hstack(blocks).reshape(-1, 3, sum(b.shape[1] for b in blocks)), names


def scored_covariances(
    problem: Problem, state: State, covariance: JointCovariance, q: np.ndarray, motion: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (k * N, 3) of the scored points at configurations q, point-major, and the
    covariance (k * N, 3, 3) of each one's error, the score's gauge removed (over all of them)."""
    scored = problem.formulation.scored(problem, state)
    positions = scored_positions(problem.robot, problem.frame, state.params, q, motion, scored)
    if not covariance.released:
        return positions, np.zeros((len(positions), 3, 3))
    J, names = scored_jacobian(problem, state, scored, covariance.released, q, motion)
    gauge = problem.formulation.gauge(problem.settings)
    flat = without_gauge(J.reshape(-1, J.shape[2]), positions, gauge).reshape(len(positions), 3, -1)
    block = covariance.block(names)
    return positions, np.einsum("nij,jk,nlk->nil", flat, block, flat)


def predicted_against_truth(
    problem: Problem, state: State, covariance: JointCovariance, q: np.ndarray, motion: np.ndarray | None, factor: float
) -> Prediction | None:
    """Predicted RMS (m) of the score against the truth at q: the estimate's uncertainty
    carried to the scored points, the gauge removed; no noise (the truth is exact)."""
    if not len(q) or not covariance.released:
        return None
    _, covariances = scored_covariances(problem, state, covariance, q, motion)
    variance = float(np.mean(np.trace(covariances, axis1=1, axis2=2)))
    assumes = truth_blind_spots(problem, state, covariance.released, q, motion)
    return Prediction(float(np.sqrt(variance)), float(np.sqrt(variance)), 0.0, factor, assumes)


def truth_blind_spots(
    problem: Problem, state: State, released: Sequence[str], q: np.ndarray, motion: np.ndarray | None
) -> tuple[BlindSpot, ...]:
    """The candidates the calibration fixed that move the scored points at q where nothing
    released (nor the score's gauge) takes their effect (fgcal.calibration.blind_spots)."""
    fixed = [name for name in problem.candidates if name not in set(released)]
    if not fixed:
        return ()
    scored = problem.formulation.scored(problem, state)
    positions = scored_positions(problem.robot, problem.frame, state.params, q, motion, scored)
    # One Jacobian on [P released, P fixed, the score's unknowns], its gauge removed once.
    J, _ = scored_jacobian(problem, state, scored, [*released, *fixed], q, motion)
    J = without_gauge(J.reshape(-1, J.shape[2]), positions, problem.formulation.gauge(problem.settings))
    m, f = len(released), len(fixed)
    return blind_spots(np.hstack([J[:, :m], J[:, m + f :]]), J[:, m : m + f], fixed)


def workspace_map(
    problem: Problem, state: State, covariance: JointCovariance | None, q: np.ndarray, motion: np.ndarray | None
) -> dict | None:
    """Where the robot was checked and how well it is known there: at each held-out
    configuration the first scored point in W (m) and its predicted sigma (m, the score's gauge
    removed, no noise)."""
    if not len(q) or covariance is None or not covariance.released:
        return None
    positions, covariances = scored_covariances(problem, state, covariance, q, motion)
    positions, covariances = positions[: len(q)], covariances[: len(q)]  # the first point
    instrument = problem.formulation.scored(problem, state).instrument
    if instrument is not None:  # from the score's frame into W
        T_W_I = np.linalg.inv(instrument)
        positions = positions @ T_W_I[:3, :3].T + T_W_I[:3, 3]
    return {"positions_m": positions, "predicted_sigma_m": np.sqrt(np.trace(covariances, axis1=1, axis2=2))}
