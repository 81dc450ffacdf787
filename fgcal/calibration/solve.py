"""Staged solving: each stage's graph minimised by GTSAM's LevenbergMarquardtOptimizer."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import gtsam
import numpy as np

from ..model.parameters import kind_label
from .graph import StageGraph, build_graph
from .problem import Problem, read_state
from .results import StageReport
from .state import State

# GTSAM's defaults for lambda; the stopping rule is scipy.optimize.least_squares' default ftol:
# a relative cost change below 1e-8.
RELATIVE_TOLERANCE, ABSOLUTE_TOLERANCE = 1e-8, 1e-14


def selects(stage: Sequence[str], name: str) -> bool:
    """Whether a stage releases the parameter ``name``: its kind or its name is listed (a
    ``{kind, joints}`` entry is listed as the names), and no ``"!name"`` holds it fixed."""
    return (kind_label(name) in stage or name in stage) and f"!{name}" not in stage


def stage_parameters(kinds: Sequence[str], identifiable: Sequence[str]) -> list[str]:
    """The identifiable parameters a stage releases (selects)."""
    return [name for name in identifiable if selects(kinds, name)]


def releasable(candidates: Sequence[str], stages: Sequence[Sequence[str]]) -> list[str]:
    """The candidates that some stage releases. Only these are judged for identifiability: a
    parameter no stage releases stays at its nominal value whatever the analysis says, so it
    must not win a pivoted selection and fix a released parameter as "a combination of" it."""
    return [name for name in candidates if any(selects(stage, name) for stage in stages)]


def optimise(stage: StageGraph, max_iterations: int) -> tuple[gtsam.Values, int]:
    """Minimise the stage graph's error with GTSAM's Levenberg-Marquardt; returns the values and
    the iterations taken.

    Each step is solved by multifrontal QR: the Jacobian's columns span lengths (m), angles
    (rad) and compliances (rad/(N m), about 1e-7), and QR does not square their spread as the
    normal equations would. Diagonal damping scales lambda to each column. A trial step so long
    that a measurement model breaks down (a point behind the camera) costs so much that it is
    rejected (fgcal.factors.MeasurementFactor)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(RELATIVE_TOLERANCE)
    params.setAbsoluteErrorTol(ABSOLUTE_TOLERANCE)
    optimizer = gtsam.LevenbergMarquardtOptimizer(stage.graph, stage.values, params)
    return optimizer.optimize(), int(optimizer.iterations())


def measurement_residuals(stage: StageGraph, values: gtsam.Values) -> tuple[float, dict[str, float]]:
    """sqrt of the sum of squared whitened measurement residuals (no robust loss), and the RMS
    of the raw residuals per unit of the rows (m, rad, px): a 6D pose's rows are not mixed."""
    whitened = 0.0
    sums: dict[str, list[float]] = {}
    for measurements in stage.measurements:
        residual = measurements.raw_residual(values)
        whitened += float(np.sum((residual / measurements.sigma) ** 2))
        for unit, rows in measurements.row_units().items():
            total = sums.setdefault(unit, [0.0, 0])
            total[0] += float(np.sum(residual[rows] ** 2))
            total[1] += int(np.count_nonzero(rows))
    return float(np.sqrt(whitened)), {unit: float(np.sqrt(s / max(n, 1))) for unit, (s, n) in sums.items()}


def solve_stage(
    problem: Problem, name: str, released: list[str], state: State, say: Callable[[str], None] = lambda _m: None
) -> tuple[State, StageReport, StageGraph, gtsam.Values]:
    started = time.perf_counter()
    cpu = time.process_time()
    stage = build_graph(problem, released, state)
    result, iterations = optimise(stage, problem.max_iterations)
    new_state = read_state(state, stage.keys, result, stage.kinematics)
    # With a robust loss, the scale of its threshold was taken from the residuals at the stage's
    # start; once the model fits better, re-take it and solve again, until it settles.
    for _ in range(5):
        if stage.robust_scale is None:
            break
        retaken = problem.formulation.robust_loss(problem, stage.measurements, result)
        if retaken is None or np.all(np.asarray(retaken[1]) > 0.9 * np.asarray(stage.robust_scale)):
            break
        stage = build_graph(problem, released, new_state)
        result, more = optimise(stage, problem.max_iterations)
        iterations += more
        new_state = read_state(new_state, stage.keys, result, stage.kinematics)
    norm, rms = measurement_residuals(stage, result)
    report = StageReport(
        name,
        list(released),
        norm,
        rms,
        iterations,
        time.perf_counter() - started,
        time.process_time() - cpu,
        len(released) + state.n_auxiliary,
        problem.n_residuals,
    )
    say(f"  stage {name}: {len(released)} parameters, {iterations} iterations, residual RMS {report.rms_text()}, "
        f"{report.time_s:.2f} s")  # fmt: skip
    # What later steps ask of a solved stage is at its solution (covariance, rejection): the
    # optimiser's trial points go, tens of MB each at thousands of configurations.
    for kinematics in stage.every_kinematics():
        kinematics.keep_only(result.atVector(stage.keys.params) if stage.keys.params is not None else None)
    return new_state, report, stage, result
