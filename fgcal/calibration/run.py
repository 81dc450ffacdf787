"""``fgcal calibrate``: identifiability, staged solving, covariances, validation."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .. import kinematics
from ..dataset import Dataset, load_dataset
from ..errors import InputError
from .config import CalibrationConfig
from .covariance import JointCovariance, joint_covariance
from .goodness import Fit
from .graph import FIXTURE_KEY, P_KEY, build_graph, chi_median, robust_scale
from .identifiability import Identifiability, analyse
from .initialise import initial_state
from .models import compare_models
from .prediction import predicted_held_out
from .problem import PairGroup, Problem, build_problem, pair_groups
from .references import reference_check
from .solve import StageReport, solve_stage, stage_parameters
from .state import State
from .validation import SCORES, ErrorStats, default_tool_point, held_out_errors, primary_score, stats


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
    model_comparison: list[dict] | None = None  # with model: auto or compare_models (calibration.models)
    compensation: dict | None = None  # scoring.compensation_study, when a simulation's truth scores it
    covariance_declared: np.ndarray | None = None  # under the declared noise, unscaled
    validation: dict[str, dict[str, ErrorStats]] = field(default_factory=dict)
    truth: dict | None = None
    timing: dict[str, float] = field(default_factory=dict)
    references: dict | None = None  # the tracker's stability (calibration.references)

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


# The first stage explains the data with the nominal robot (or a few offsets): a residual RMS
# beyond both of these is no kinematic error (a 125 kg arm is off by 1-2 cm) but data that do
# not belong to the model.
GROSS_RESIDUAL = {"m": 0.05, "px": 500.0}  # px: a third of an image; the nominal robot alone leaves 150
GROSS_SIGMAS = 1000.0

LIKELY_CAUSES = {
    "tracker": "the tracker points do not belong to their configurations (rows shifted, configuration ids "
    "mismatched), reflector names swapped between targets, joint angles or lengths in other units than "
    "units: declares, or another robot than the one that moved",
    "touch": "touch rows naming the wrong point, joint angles in other units than units: declares, or another "
    "robot than the one that moved",
    "pairs": "camera points in another unit or frame, point names that do not match the drawing, a wrong "
    "camera mounting or fixture pose, or joint angles in other units than units: declares",
    "projection": "pixels matched to the wrong points, wrong intrinsics, a camera mounting far from the "
    "dataset's, or joint angles in other units than units: declares",
    "static_camera": "pixels matched to the wrong board points, wrong intrinsics, images that do not belong to "
    "their configurations, or joint angles in other units than units: declares",
    "poses": "poses that do not belong to their configurations (rows shifted), quaternions in another order "
    "than qw, qx, qy, qz or inverted poses (the instrument in the probe's frame), joint angles or lengths in "
    "other units than units: declares, or another robot than the one that moved",
    "distances": "readings that do not belong to their configurations or pivots, a ballbar's deviation from its "
    "nominal length instead of its full length, joint angles or lengths in other units than units: declares",
}


def _check_first_stage(problem: Problem, report: StageReport, stage, values) -> None:
    """Refuse to go on when the first stage leaves the typical residual (the median over the
    observations of their RMS per coordinate: a few gross misreads are the robust loss's job)
    far above both the declared noise and anything a kinematic error explains (GROSS_RESIDUAL,
    GROSS_SIGMAS)."""
    config = problem.config
    measurements = stage.measurements[0]
    # In the report's unit (a 6D pose's whitened residual is counted in position sigmas).
    sigma = config.pixel_sigma_px if report.unit == "px" else config.measurement_sigma_m
    typical = float(np.median(measurements.unit_rms(values))) * sigma
    if typical <= GROSS_RESIDUAL[report.unit] or typical <= GROSS_SIGMAS * sigma:
        return
    size = f"{typical:.3g} px" if report.unit == "px" else f"{typical * 1e3:.4g} mm"
    raise InputError(
        problem.dataset.path,
        None,
        f"the data cannot be explained: after stage {report.name} the typical residual is {size} per "
        f"coordinate, {typical / sigma:.3g} times the declared noise and beyond any kinematic error "
        f"({GROSS_RESIDUAL[report.unit]:g} {report.unit}). No robot was written. Likely causes: "
        f"{LIKELY_CAUSES[config.formulation]}.",
    )


REJECT_SIGMA = 5.0
MAX_REJECTED_FRACTION = 0.1
REJECTION_ROUNDS = 3


def reject_outliers(problem: Problem, stage, values) -> bool:
    """Remove gross outliers after the last stage and name them in problem.rejected; True when
    some were removed (the last stage is then solved again).

    - pixels and tracker points, when the config asks for a robust loss on them: an
      observation whose whitened residual RMS exceeds REJECT_SIGMA times the residuals'
      robust scale;
    - camera points of the pair formulation (always): in a group every observation's
      ``X c - R_W_F p`` is the same point (the unknown base offset) plus noise, so an
      observation farther than REJECT_SIGMA robust sigmas from its group's median is a gross
      error. (The pair contrasts mix a group's observations and cannot name one.)

    Thresholds are in units of the residuals' robust scale: when the model cannot fit the data
    to the declared noise, everything is many sigmas and nothing is an outlier; and nothing is
    removed when more than MAX_REJECTED_FRACTION would go (a model problem, not bad data)."""
    if problem.config.formulation == "pairs":
        return _reject_pairs(problem, stage, values)
    # The measurement kind, its observations and the name of each one's point or target.
    kind, observations, name_of = {
        "projection": ("pixels", problem.pixel_obs, lambda o: o[3]),
        "tracker": ("tracker_points", problem.tracker_obs, lambda o: problem.targets[o[1]]),
        "touch": ("touch_points", problem.touch_obs, lambda o: problem.touch_points[o[1]]),
        "static_camera": ("pixels", problem.pixel_obs, lambda o: o[3]),
        "poses": ("tracker_poses", problem.pose_obs, lambda o: "pose"),
        "distances": (
            "distances",
            problem.distance_obs,
            lambda o: problem.pivots[o[1]] if o[1] >= 0 else "between configurations",
        ),
    }[problem.config.formulation]
    if problem.config.robust.get(kind) is None:
        return False
    measurements, order = stage.measurements[0], stage.observations[0]
    scale = robust_scale(stage.measurements, values)
    rms = np.zeros(len(observations))
    rms[order] = measurements.unit_rms(values)
    outlier = rms > REJECT_SIGMA * scale
    if not outlier.any() or outlier.sum() > MAX_REJECTED_FRACTION * len(outlier):
        return False
    unit = "px" if kind == "pixels" else "m"
    # The declared sigma of the kind, as the set was whitened (a pose: its position's).
    sigma = float(measurements.sigma[-1])
    for o, size in zip(observations, rms, strict=True):
        if size > REJECT_SIGMA * scale:
            problem.rejected.append(_rejection(problem, o[0], kind, name_of(o), size, size * sigma, unit))
    observations[:] = [o for o, bad in zip(observations, outlier, strict=True) if not bad]
    return True


def _flag_held_out_pairs(problem: Problem, state: State) -> None:
    """The same gross-error test on the held-out images' camera points, with the final model:
    named like the rejected ones (``held_out``), and left out of the held-out pair score."""
    groups = pair_groups(problem, problem.test)
    if not groups:
        return
    q = problem.dataset.q[problem.test]
    poses = kinematics.frame_pose(problem.robot, kinematics.forward(problem.robot, state.params, q), "tool")
    rotation = state.fixture_rotation if state.fixture_rotation is not None else problem.fixture_rotation
    sigma = problem.config.camera_point_sigma_m
    deviations, threshold = _pair_deviations(groups, poses, rotation, sigma)
    every = np.concatenate(deviations)
    if (every > threshold).sum() > MAX_REJECTED_FRACTION * len(every):
        return
    for group, deviation in zip(groups, deviations, strict=True):
        for o in np.flatnonzero(deviation > threshold):
            entry = _rejection(
                problem, group.images[group.owner[o]], "camera_points", group.names[o], deviation[o],
                deviation[o] * sigma, "m", problem.test,
            )  # fmt: skip
            problem.rejected.append({**entry, "held_out": True})


def _rejection(
    problem: Problem,
    index: int,
    kind: str,
    name: str,
    sigmas: float,
    size: float,
    unit: str,
    subset: np.ndarray | None = None,
) -> dict:
    key = "target" if kind == "tracker_points" else "point"
    return {
        "config": str(problem.dataset.configs[(problem.fit if subset is None else subset)[index]]),
        "kind": kind,
        key: name,
        "size_sigma": float(sigmas),
        f"size_{unit}": float(size),
    }


def _pair_deviations(
    groups: list[PairGroup], poses: np.ndarray, rotation: np.ndarray, sigma: float
) -> tuple[list[np.ndarray], float]:
    """Per group, each observation's distance (in sigmas) from its group's median of
    ``X c - R_W_F p``, and the rejection threshold (REJECT_SIGMA robust sigmas of a 3-D point)."""
    deviations = []
    for group in groups:
        T = poses[np.array(group.images)[group.owner]]
        world = np.einsum("oij,oj->oi", T[:, :3, :3], group.c) + T[:, :3, 3] - group.p_F @ rotation.T
        deviations.append(np.linalg.norm(world - np.median(world, axis=0), axis=1) / sigma)
    every = np.concatenate(deviations) if deviations else np.zeros(0)
    median_3d = float(chi_median(np.array([3]))[0])
    scale = max(1.0, float(np.median(every)) / median_3d) if every.size else 1.0
    return deviations, REJECT_SIGMA * median_3d * scale


def _reject_pairs(problem: Problem, stage, values) -> bool:
    params = values.atVector(P_KEY) if stage.released else None
    rotation = values.atRot3(FIXTURE_KEY).matrix() if stage.aux.get(FIXTURE_KEY) else problem.fixture_rotation
    sigma = problem.config.camera_point_sigma_m
    deviations, threshold = _pair_deviations(problem.pairs, stage.model.poses(params), rotation, sigma)
    every = np.concatenate(deviations)
    if not (every > threshold).any() or (every > threshold).sum() > MAX_REJECTED_FRACTION * len(every):
        return False
    kept_groups = []
    for group, deviation in zip(problem.pairs, deviations, strict=True):
        bad = deviation > threshold
        for o in np.flatnonzero(bad):
            index = group.images[group.owner[o]]
            problem.rejected.append(
                _rejection(problem, index, "camera_points", group.names[o], deviation[o], deviation[o] * sigma, "m")
            )
        keep = ~bad
        if keep.sum() >= 2:
            used = sorted(set(group.owner[keep].tolist()))
            renumber = {old: new for new, old in enumerate(used)}
            kept_groups.append(
                PairGroup(
                    images=[group.images[i] for i in used],
                    owner=np.array([renumber[i] for i in group.owner[keep]]),
                    c=group.c[keep],
                    p_F=group.p_F[keep],
                    labels=[group.labels[i] for i in used],
                    names=[n for n, k in zip(group.names, keep, strict=True) if k],
                )
            )
    problem.pairs = kept_groups
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
    if config.model == "auto" or config.compare_models:
        result, table = compare_models(lambda c: calibrate_dataset(dataset, c, progress), config, say)
        result.model_comparison = table
        return result
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
    # The mounting components the data cannot determine stay at the nominal mounting, not at
    # the hand-eye guess: the guess is noisy, and a fixed value is no estimate.
    nominal = problem.robot.parameter_vector()
    for name in identifiability.unidentifiable:
        if name.startswith("tool."):
            state.params[problem.robot.parameter_names.index(name)] = nominal[problem.robot.parameter_names.index(name)]
    stages: list[StageReport] = []
    solve_started = time.perf_counter()
    if state.n_auxiliary:
        state, report, first_stage, first_values = solve_stage(problem, "0 (auxiliary unknowns)", [], state, say)
        stages.append(report)
        _check_first_stage(problem, report, first_stage, first_values)
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
        if len(stages) == 1:
            _check_first_stage(problem, report, last_stage, last_values)
    for _ in range(REJECTION_ROUNDS):  # again while the refit shows more: a biased fit hides some
        if last_stage is None or not reject_outliers(problem, last_stage, last_values):
            break
        say(
            f"  rejected {len(problem.rejected)} measurements beyond {REJECT_SIGMA:g} sigma in all; "
            "solving the last stage again"
        )
        state, report, last_stage, last_values = solve_stage(
            problem, f"{len(config.stages)} (after rejection)", last_stage.released, state, say
        )
        stages.append(report)
    if last_stage is not None:
        state, last_stage, last_values, final_ident = _identifiable_at_solution(
            problem, identifiability, state, last_stage, last_values, stages, say
        )
    if config.formulation == "pairs":
        _flag_held_out_pairs(problem, state)
    solve_time = time.perf_counter() - solve_started
    joint = joint_covariance(last_stage, last_values) if last_stage is not None else None
    covariance = joint.block([P_KEY]) if joint is not None else np.zeros((0, 0))
    released = list(last_stage.released) if last_stage is not None else []
    point = default_tool_point(problem, state)
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
    result.references = reference_check(problem.dataset, config.tracker_sigma_m)
    if result.references is not None:
        misreads = sum(len(t.get("misreads", [])) for t in result.references["targets"].values())
        say(
            f"  tracker references: common drift {result.references['common_drift_norm_m'] * 1e3:.3g} mm over the "
            f"session, {misreads} gross misreads"
        )
    result.timing = {"solve_s": solve_time, "total_s": time.perf_counter() - started}
    return result


def _identifiable_at_solution(problem, identifiability, state, stage, values, stages, say):
    """The identifiability analysis again at the solution, on the released parameters.

    At the starting point the residuals are far above the noise, and a direction that only
    changes the residuals in proportion to themselves (a common scale of every length and
    touched point, a rotation about the vertical when compliances have gravity moments) looks
    determined there; at the solution it is not. Released parameters found unidentifiable at
    the solution are fixed at their estimates (gauge directions: any value fits as well) and the
    last stage is solved again, so that the covariance describes only what the data determine."""
    at_solution = analyse(build_graph(problem, stage.released, state), problem.config.min_information)
    dropped = [name for name in stage.released if name in at_solution.unidentifiable]
    again = at_solution
    if dropped:
        say(
            f"  at the solution {len(dropped)} released parameters are not identifiable ({', '.join(dropped)}): "
            "fixed at their estimates, solving the last stage again"
        )
        kept = [name for name in stage.released if name not in dropped]
        state, report, stage, values = solve_stage(problem, f"{stages[-1].name} (identifiable set)", kept, state, say)
        stages.append(report)
        again = analyse(build_graph(problem, kept, state), problem.config.min_information)
    unidentifiable = dict(identifiability.unidentifiable)
    absorbed_by = dict(identifiability.absorbed_by)
    for name in dropped:
        unidentifiable[name] = f"at the solution, {at_solution.unidentifiable[name]}"
        if name in at_solution.absorbed_by:
            absorbed_by[name] = at_solution.absorbed_by[name]
    final = Identifiability(
        again.identifiable,
        unidentifiable,
        again.singular_values,
        again.condition_number,
        again.n_rows,
        absorbed_by,
    )
    return state, stage, values, final


def held_out_summary(result: CalibrationResult) -> str | None:
    """One line on the held-out error before and after, or None when nothing was scored."""
    scores = [primary_score(result.validation, label) for label in ("before", "after")]
    if scores[1] is None:
        return None
    (key, before), (_, after) = scores
    if key != "tool_point":
        return (
            f"  held-out {SCORES[key]} (no truth: the held-out measurements): before {before.rms:.3e} m "
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
