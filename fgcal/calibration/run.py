"""``fgcal calibrate``: identifiability, staged solving, covariances, validation."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..dataset import Dataset, load_dataset
from ..errors import InputError
from .config import CalibrationConfig
from .covariance import JointCovariance, joint_covariance
from .goodness import Fit
from .graph import P_KEY, build_graph, robust_scale
from .identifiability import Identifiability, analyse
from .initialise import initial_state
from .problem import Problem, build_problem
from .solve import StageReport, solve_stage, stage_parameters
from .state import State
from .validation import ErrorStats, default_tool_point, held_out_errors, predicted_held_out, primary_score, stats


@dataclass
class CalibrationResult:
    config: CalibrationConfig
    problem: Problem
    identifiability: Identifiability
    final_identifiability: Identifiability
    stages: list[StageReport]
    before: State
    state: State
    released: list[str]
    covariance: np.ndarray  # of the released parameters, scaled by the fit's variance factor
    tool_point: np.ndarray
    fit: Fit | None = None  # goodness of fit of the last stage
    joint_covariance: JointCovariance | None = None  # (P, auxiliary unknowns), scaled like covariance
    covariance_declared: np.ndarray | None = None  # under the declared noise, unscaled
    validation: dict[str, dict[str, ErrorStats]] = field(default_factory=dict)
    truth: dict | None = None
    timing: dict[str, float] = field(default_factory=dict)

    @property
    def sigmas(self) -> dict[str, float]:
        return {n: float(np.sqrt(max(self.covariance[i, i], 0.0))) for i, n in enumerate(self.released)}


def _check_enough(problem: Problem, parameters: list[str], state: State) -> None:
    """At least two residuals per unknown: the candidate parameters (before any is found
    unidentifiable, so thin data are refused rather than quietly reduced) and the auxiliary
    unknowns."""
    unknowns = len(parameters) + state.n_auxiliary
    if problem.n_residuals < 2 * unknowns:
        raise InputError(
            problem.dataset.path,
            None,
            f"too few measurements: {problem.n_residuals} residuals for {unknowns} unknowns "
            f"(at least twice as many needed)",
        )


REJECT_SIGMA = 5.0
MAX_REJECTED_FRACTION = 0.1


def reject_outliers(problem: Problem, stage, values) -> bool:
    """Remove per-observation measurements (pixels, tracker points) whose whitened residual
    exceeds REJECT_SIGMA at the solution of the last stage, when the config asks for a robust
    loss on them; they are listed in the report. Pair groups mix many observations and keep
    only the robust loss."""
    kind = {"projection": "pixels", "tracker": "tracker_points"}.get(problem.config.formulation)
    if kind is None or problem.config.robust.get(kind) is None:
        return False
    observations = problem.pixel_obs if kind == "pixels" else problem.tracker_obs
    # In units of the residuals' robust scale, like the robust loss: when the model cannot fit
    # the data to the declared noise, everything is many sigmas and nothing is an outlier.
    threshold = REJECT_SIGMA * robust_scale(stage.measurements, values)
    measurements, order = stage.measurements[0], stage.observations[0]
    dims = np.diff(np.append(measurements.unit_starts, measurements.n_rows))
    rms = measurements.unit_norms(values) / np.sqrt(dims)
    outlier = np.zeros(len(observations), dtype=bool)
    outlier[order] = rms > threshold
    if not outlier.any() or outlier.sum() > MAX_REJECTED_FRACTION * len(outlier):
        return False  # more than a few "outliers" means a model problem, not bad measurements
    problem.rejected += [(int(problem.fit[o[0]]), kind) for o, bad in zip(observations, outlier, strict=True) if bad]
    observations[:] = [o for o, bad in zip(observations, outlier, strict=True) if not bad]
    return True


def calibrate(config: CalibrationConfig, progress: Callable[[str], None] | None = None) -> CalibrationResult:
    """Load the config's dataset and calibrate (see :func:`calibrate_dataset`)."""
    return calibrate_dataset(load_dataset(config.dataset), config, progress)


def calibrate_dataset(
    dataset: Dataset, config: CalibrationConfig, progress: Callable[[str], None] | None = None
) -> CalibrationResult:
    """Identifiability analysis, staged solving, covariances and validation on the held-out
    measurements. A simulation's truth is not read here: score the result afterwards with
    fgcal.calibration.scoring.score_with_truth."""
    say = progress or (lambda _m: None)
    started = time.perf_counter()
    problem = build_problem(dataset, config, say)
    say(
        f"calibrating {problem.robot.name}, model {config.model}, {config.formulation} formulation: "
        f"{len(problem.fit)} configurations for fitting, {len(problem.test)} held out, "
        f"{problem.n_residuals} residuals"
    )
    if problem.detection:
        say(
            f"  detection: {problem.detection['corners']} corners in {problem.detection['images']} images, "
            f"{problem.detection['rejected_by_gate']} rejected by the gate, "
            f"{len(problem.skipped_images)} images skipped"
        )
        for cid, reason in problem.skipped_images:
            say(f"    skipped {cid}: {reason}")
    state = initial_state(problem)
    _check_enough(problem, problem.candidates, state)
    t = time.perf_counter()
    identifiability = analyse(build_graph(problem, problem.candidates, state), config.min_information)
    say(
        f"  identifiability: {len(identifiability.identifiable)} of {len(problem.candidates)} candidates "
        f"identifiable, condition number {identifiability.condition_number:.3g} ({time.perf_counter() - t:.2f} s)"
    )
    stages: list[StageReport] = []
    solve_started = time.perf_counter()
    if state.tracker_pose is not None or state.fixture_rotation is not None or state.fixture_pose is not None:
        state, report, _, _ = solve_stage(problem, "0 (auxiliary unknowns)", [], state, say)
        stages.append(report)
    before = state
    final_ident = identifiability
    last_stage = last_values = None
    for i, kinds in enumerate(config.stages, start=1):
        released = stage_parameters(kinds, identifiability.identifiable)
        if not released:
            say(f"  stage {i}: nothing identifiable to release ({', '.join(kinds)})")
            continue
        state, report, last_stage, last_values = solve_stage(problem, str(i), released, state, say)
        stages.append(report)
    if last_stage is not None and reject_outliers(problem, last_stage, last_values):
        say(
            f"  rejected {len(problem.rejected)} measurements beyond {REJECT_SIGMA:g} sigma; "
            "solving the last stage again"
        )
        state, report, last_stage, last_values = solve_stage(
            problem, f"{len(config.stages)} (after rejection)", last_stage.released, state, say
        )
        stages.append(report)
    solve_time = time.perf_counter() - solve_started
    joint = joint_covariance(last_stage, last_values) if last_stage is not None else None
    covariance = joint.block([P_KEY]) if joint is not None else np.zeros((0, 0))
    released = list(last_stage.released) if last_stage is not None else []
    point = default_tool_point(problem)
    fit = stages[-1].fit if stages else None
    factor = fit.variance_factor if fit is not None else 1.0
    result = CalibrationResult(
        config,
        problem,
        identifiability,
        final_ident,
        stages,
        before,
        state,
        released,
        covariance * factor,
        point,
        fit=fit,
        covariance_declared=covariance,
        joint_covariance=joint.scaled(factor) if joint is not None else None,
    )
    if fit is not None and not fit.consistent:
        say(f"  {fit.sentence()}")
    for label, st in (("before", before), ("after", state)):
        result.validation[label] = {k: stats(v) for k, v in held_out_errors(problem, st).items()}
    result.timing = {"solve_s": solve_time, "total_s": time.perf_counter() - started}
    return result


def held_out_summary(result: CalibrationResult) -> str | None:
    """One line on the held-out error before and after, or None when nothing was scored."""
    scores = [primary_score(result.validation, label) for label in ("before", "after")]
    if scores[1] is None:
        return None
    (key, before), (_, after) = scores
    if key == "point_pair":
        return (
            f"  held-out point-pair error (no truth: the held-out images' point pairs): before {before.rms:.3e} m "
            f"RMS, after {after.rms:.3e} m"
            + (f" (predicted {p['rms']:.3e} m)" if (p := predicted_held_out(result, against_truth=False)) else "")
        )
    reference = "the simulation's truth" if result.truth else "the held-out measurements"
    line = (
        f"  held-out positioning error against {reference}: before {before.rms:.3e} m RMS, after {after.rms:.3e} m RMS"
    )
    predicted = predicted_held_out(result, against_truth=result.truth is not None)
    if predicted:
        line += f" (predicted {predicted['rms']:.3e} m)"
    return line
