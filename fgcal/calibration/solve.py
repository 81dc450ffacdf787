"""Staged solving on the factor graph with GTSAM's Levenberg-Marquardt."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..parameters import split_name
from .graph import StageGraph, build_graph, read_state, robust_scale
from .problem import Problem
from .state import State


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
    """sqrt of the sum of squared whitened measurement residuals, and their RMS in the
    measurements' unit, without the robust loss."""
    whitened, raw, count = 0.0, 0.0, 0
    for measurements in stage.measurements:
        residual = measurements.raw_residual(values)
        whitened += float(np.sum((residual / measurements.sigma) ** 2))
        raw += float(np.sum(residual**2))
        count += residual.size
    return float(np.sqrt(whitened)), float(np.sqrt(raw / max(count, 1)))


def optimise(stage: StageGraph, max_iterations: int) -> tuple[gtsam.Values, int]:
    """GTSAM's Levenberg-Marquardt on the stage graph.

    Multifrontal QR: the Jacobian's columns span lengths (m), angles (rad) and compliances
    (rad/(N m), about 1e-7), and QR does not square their spread as the normal equations
    would. Diagonal damping makes the steps independent of those units. The stopping rule is
    scipy.optimize.least_squares' default ftol: a relative cost change below 1e-8.
    """
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-8)
    params.setAbsoluteErrorTol(1e-14)
    optimizer = gtsam.LevenbergMarquardtOptimizer(stage.graph, stage.values, params)
    values = optimizer.optimize()
    return values, int(optimizer.iterations())


def solve_stage(
    problem: Problem, name: str, released: list[str], state: State, say: Callable[[str], None] = lambda _m: None
) -> tuple[State, StageReport, StageGraph, gtsam.Values]:
    started = time.perf_counter()
    stage = build_graph(problem, released, state)
    result, iterations = optimise(stage, problem.config.max_iterations)
    new_state = read_state(stage, result, state)
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
        new_state = read_state(stage, result, new_state)
    norm, rms = measurement_residuals(stage, result)
    unit = "px" if problem.config.formulation == "projection" else "m"
    report = StageReport(name, released, norm, rms, unit, iterations, time.perf_counter() - started)
    say(
        f"  stage {name}: {len(released)} parameters, {report.iterations} iterations, "
        f"residual RMS {rms:.3e} {unit}, {report.time_s:.2f} s"
    )
    return new_state, report, stage, result
