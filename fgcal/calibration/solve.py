"""Staged solving on the factor graph: Gauss-Newton with variable projection on GTSAM QR."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..parameters import split_name
from .graph import P_KEY, StageGraph, State, build_graph, read_state, robust_scale
from .problem import Problem


@dataclass
class StageReport:
    name: str
    released: list[str]
    residual_norm: float  # sqrt(sum of squared whitened measurement residuals)
    residual_rms: float  # RMS of the measurement residuals, in unit
    unit: str  # m, or px for the projection formulation
    iterations: int
    time_s: float


def kind_label(name: str) -> str:
    kind, owner = split_name(name)
    return owner if isinstance(owner, str) else kind


def stage_parameters(kinds: Sequence[str], identifiable: Sequence[str]) -> list[str]:
    """The identifiable parameters whose kind is released in a stage."""
    return [name for name in identifiable if kind_label(name) in kinds]


def measurement_residuals(stage: StageGraph, values: gtsam.Values) -> tuple[float, float]:
    whitened, raw, count = 0.0, 0.0, 0
    for factor in stage.measurements:
        residual, _ = factor.checked(factor.read(values), False)
        whitened += float(np.sum((residual / factor.sigmas) ** 2))
        raw += float(np.sum(residual**2))
        count += residual.size
    return float(np.sqrt(whitened)), float(np.sqrt(raw / max(count, 1)))


def project(stage: StageGraph, values: gtsam.Values) -> gtsam.Values:
    """Put every pose variable exactly on the kinematics of the current parameters."""
    if not stage.released:
        return values
    poses = stage.model.poses(values.atVector(P_KEY))
    projected = gtsam.Values(values)
    for key, j in stage.pose_index.items():
        projected.update(key, gtsam.Pose3(poses[j]))
    return projected


def optimise(stage: StageGraph, max_iterations: int) -> tuple[gtsam.Values, int]:
    """Gauss-Newton with variable projection and backtracking, on GTSAM's QR elimination.

    The pose variables are tied to FK(P) far more tightly than the measurements constrain
    them. A step that is right to first order then leaves second-order tie residuals that
    dominate the cost, so plain Levenberg-Marquardt crawls. Here each Gauss-Newton step
    (solved on the linearised graph, poses and parameters together) is followed by putting
    every pose exactly on FK(P), and the step is accepted on that projected error, halved
    while the error grows. At the optimum the poses equal FK(P) to within the tie, so only
    the path changes, not the answer.
    """
    values = project(stage, stage.values)
    error = stage.graph.error(values)
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        step = stage.graph.linearize(values).optimize(gtsam.EliminateQR)
        scale, accepted = 1.0, False
        while scale >= 1e-4:
            candidate = project(stage, values.retract(step.scale(scale)))
            new_error = stage.graph.error(candidate)
            if new_error <= error:
                accepted = True
                break
            scale /= 2.0
        if not accepted:
            break
        # Same criterion as scipy.optimize.least_squares' default ftol: relative cost change 1e-8.
        converged = error - new_error <= 1e-8 * error + 1e-14
        values, error = candidate, new_error
        if converged:
            break
    return values, iterations


def solve_stage(
    problem: Problem, name: str, released: list[str], state: State, say: Callable[[str], None] = lambda _m: None
) -> tuple[State, StageReport, StageGraph, gtsam.Values]:
    started = time.perf_counter()
    stage = build_graph(problem, released, state)
    result, iterations = optimise(stage, problem.config.max_iterations)
    new_state = read_state(problem, stage, result, state)
    # With a robust loss, the scale of its threshold was taken from the residuals at the stage's
    # start; once the model fits better, re-take it and solve again, until it settles.
    for _ in range(5):
        if stage.robust_scale is None:
            break
        new_scale = robust_scale(stage.measurements, result)
        if new_scale > 0.9 * stage.robust_scale:
            break
        stage = build_graph(problem, released, new_state)
        result, more = optimise(stage, problem.config.max_iterations)
        iterations += more
        new_state = read_state(problem, stage, result, new_state)
    norm, rms = measurement_residuals(stage, result)
    unit = "px" if problem.config.formulation == "projection" else "m"
    report = StageReport(name, released, norm, rms, unit, iterations, time.perf_counter() - started)
    say(
        f"  stage {name}: {len(released)} parameters, {report.iterations} iterations, "
        f"residual RMS {rms:.3e} {unit}, {report.time_s:.2f} s"
    )
    return new_state, report, stage, result
