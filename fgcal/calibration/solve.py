"""Staged solving on the factor graph with GTSAM's Levenberg-Marquardt."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..factors import BehindCameraError, FactorError
from ..parameters import split_name
from .goodness import Fit, goodness_of_fit
from .graph import StageGraph, build_graph, linearize, read_state, robust_scale, stage_error
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
    n_unknowns: int = 0  # released parameters and auxiliary unknowns (tangent dimensions)
    n_residuals: int = 0  # measurement residuals the stage fitted

    @property
    def fit(self) -> Fit:
        return goodness_of_fit(self.residual_norm**2, self.n_residuals, self.n_unknowns)


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


def optimise(stage: StageGraph, max_iterations: int, method: str = "lm") -> tuple[gtsam.Values, int]:
    """Minimise the stage graph's error; returns the values and the iterations taken.

    ``lm`` (default): Levenberg-Marquardt as GTSAM's (lambda from 1e-5, times or over 10,
    diagonal damping, the same stopping rule), each step solved by GTSAM's multifrontal QR
    elimination, but with each measurement set linearised as one Jacobian factor and each
    trial step costed from the sets' vectorised residuals (graph.linearize, stage_error).
    GTSAM's own optimiser calls every factor's Python callback once per trial step and
    linearisation: on the FARO set (500 factors) that is most of the solve's time.
    ``gtsam_lm``: GTSAM's LevenbergMarquardtOptimizer on the same graph; same optimum
    (fgcal bench compares them).

    Both use QR: the Jacobian's columns span lengths (m), angles (rad) and compliances
    (rad/(N m), about 1e-7), and QR does not square their spread as the normal equations
    would. The stopping rule is scipy.optimize.least_squares' default ftol: a relative cost
    change below 1e-8.
    """
    if method == "gtsam_lm":
        params = gtsam.LevenbergMarquardtParams()
        params.setLinearSolverType("MULTIFRONTAL_QR")
        params.setDiagonalDamping(True)
        params.setMaxIterations(max_iterations)
        params.setRelativeErrorTol(RELATIVE_TOLERANCE)
        params.setAbsoluteErrorTol(ABSOLUTE_TOLERANCE)
        optimizer = gtsam.LevenbergMarquardtOptimizer(stage.graph, stage.values, params)
        return optimizer.optimize(), int(optimizer.iterations())
    values, error = stage.values, stage_error(stage, stage.values)
    dims = {key: dim for key, (_, dim) in stage.aux.items()}
    if stage.params_key is not None:
        dims[stage.params_key] = stage.model.n_released
    damping, iterations = LAMBDA_INITIAL, 0
    while iterations < max_iterations and damping < LAMBDA_MAX:
        iterations += 1
        linear = linearize(stage, values)
        diagonal = _hessian_diagonal(linear, dims)
        while damping < LAMBDA_MAX:
            damped = linear.clone()
            for key, d in diagonal.items():
                weights = np.sqrt(damping * np.clip(d, 1e-6, 1e32))
                damped.push_back(
                    gtsam.JacobianFactor(key, np.diag(weights), np.zeros(len(d)), gtsam.noiseModel.Unit.Create(len(d)))
                )
            candidate = values.retract(damped.optimize(gtsam.EliminateQR))
            try:
                new_error = stage_error(stage, candidate)
            except (FactorError, BehindCameraError):  # a step so long that the model breaks down
                new_error = np.inf
            if new_error < error:
                damping /= LAMBDA_FACTOR
                break
            damping *= LAMBDA_FACTOR
        else:
            break  # no step decreases the error: at the minimum to the precision available
        converged = error - new_error <= RELATIVE_TOLERANCE * error or error - new_error <= ABSOLUTE_TOLERANCE
        values, error = candidate, new_error
        if converged:
            break
    return values, iterations


LAMBDA_INITIAL, LAMBDA_FACTOR, LAMBDA_MAX = 1e-5, 10.0, 1e5  # GTSAM's LM defaults
RELATIVE_TOLERANCE, ABSOLUTE_TOLERANCE = 1e-8, 1e-14


def _hessian_diagonal(linear: gtsam.GaussianFactorGraph, dims: dict[int, int]) -> dict[int, np.ndarray]:
    """diag(A^T A) per variable of a linear graph of Jacobian factors; ``dims``: each
    variable's tangent dimension."""
    out: dict[int, np.ndarray] = {}
    for i in range(linear.size()):
        factor = linear.at(i)
        A, _ = factor.jacobian()
        column = 0
        for key in factor.keys():  # noqa: SIM118 (a GaussianFactor, not a dict)
            dim = dims[key]
            squares = np.sum(A[:, column : column + dim] ** 2, axis=0)
            out[key] = out.get(key, 0.0) + squares
            column += dim
    return out


def solve_stage(
    problem: Problem, name: str, released: list[str], state: State, say: Callable[[str], None] = lambda _m: None
) -> tuple[State, StageReport, StageGraph, gtsam.Values]:
    started = time.perf_counter()
    stage = build_graph(problem, released, state)
    result, iterations = optimise(stage, problem.config.max_iterations, problem.config.solver_method)
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
        result, more = optimise(stage, problem.config.max_iterations, problem.config.solver_method)
        iterations += more
        new_state = read_state(stage, result, new_state)
    norm, rms = measurement_residuals(stage, result)
    unit = "px" if problem.config.formulation in ("projection", "static_camera") else "m"
    report = StageReport(
        name,
        released,
        norm,
        rms,
        unit,
        iterations,
        time.perf_counter() - started,
        len(released) + state.n_auxiliary,
        problem.n_residuals,
    )
    say(
        f"  stage {name}: {len(released)} parameters, {report.iterations} iterations, "
        f"residual RMS {rms:.3e} {unit}, {report.time_s:.2f} s"
    )
    return new_state, report, stage, result
