"""``fgcal calibrate``: the pipeline, the same for every formulation (it calls only the
formulation protocol of fgcal.calibration.problem): identifiability, staged solving, outlier
rejection, covariances, held-out scores and their prediction."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.dataset import Dataset, load_dataset
from ..factors import OutsideModelError
from ..model.parameters import kind_label
from ..model.robot import MODELS
from .by_tip import measured_by_tip
from .config import CalibrationConfig
from .covariance import joint_covariance
from .formulations import formulation as registered
from .formulations.sets import Combined, Member
from .graph import StageGraph, build_graph, robust_scale
from .identifiability import Identifiability, analyse, evidence_against_fixing, motion_warning
from .models import compare_models
from .problem import (
    Detection,
    Observations,
    Problem,
    candidate_parameters,
    compliant_joints,
    fold_split,
    split,
)
from .references import reference_check
from .residual_model import check_residual_model, fit_residual_model
from .results import SCORES, CalibrationResult, StageReport, primary_score, stats
from .schema import KINDS as STAGE_KINDS
from .settings import Noise
from .solve import releasable, solve_stage, stage_parameters
from .state import State
from .validation_set import with_validation_sets

Say = Callable[[str], None]


def build_problem(dataset: Dataset, config: CalibrationConfig, say: Say | None = None) -> Problem:
    """The problem a config poses on a dataset: its formulation, the split into fitting and
    held-out configurations (a separate validation set held out too), the candidate
    parameters and the fitting observations."""
    # A config's sets: the composite of their formulations, each with the noise in effect for it.
    formulation = Combined([Member(s.name, registered(s.formulation), _in_effect(s.measurement, dataset), s.use)
                            for s in config.sets]) if config.sets else registered(config.formulation)  # fmt: skip
    if config.residual_model != "none":
        check_residual_model(formulation, config.path)
    robot = dataset.robot.with_model(config.model)
    if robot.history and not dataset.motion_history.known().any():
        raise InputError(
            config.path, "model", f"{config.model} fits the motion history, and {dataset.path / 'dataset.yaml'} "
            "gives none (order: unknown, and no before_q columns): fit DH,s,e, or give the measurement order",
        )  # fmt: skip
    for j in compliant_joints(robot, config.compliant_joints):
        if j > robot.n_links:
            raise InputError(config.path, "compliant_joints", f"joint {j} does not exist on {robot.name}")
    detection = None
    if config.pixels_from == "images" and "pixels_from" not in formulation.settings_read:
        raise InputError(config.path, "pixels_from", f"images: the {formulation.name} formulation reads no pixels")
    if config.pixels_from == "images" or any(s.pixels_from == "images" for s in config.sets):
        from ..data.images import detect_images

        detections = detect_images(dataset, progress=say)
        dataset = dataclasses.replace(dataset, tables={**dataset.tables, "pixels": detections.pixels})
        detection = Detection(len(dataset.configs), detections.corners, detections.rejected, tuple(detections.skipped))
    # The noise in effect: fgcal's defaults, what the instrument states (the dataset), what the
    # config states, the later winning.
    settings = _in_effect(config.measurement, dataset)
    if config.folds is not None and len(dataset.configs) < 2 * config.folds:  # a fold of one, and the rest
        raise InputError(config.path, "validation.folds", f"{config.folds} folds of {len(dataset.configs)} "
                         "configurations: at least two configurations a fold")  # fmt: skip
    if config.folds is not None and config.fold is not None:  # one fold held out of a fit on the others
        fit, test = fold_split(len(dataset.configs), config.folds, config.fold, config.split, config.split_seed)
    elif config.split == "ordered":  # the rows are the measurement order: the run's last part held out
        n_test = round(config.holdout * len(dataset.configs))
        fit, test = (
            np.arange(len(dataset.configs) - n_test),
            np.arange(len(dataset.configs) - n_test, len(dataset.configs)),
        )
    else:
        fit, test = split(len(dataset.configs), config.holdout, config.split_seed)
    if config.complement:
        if not len(test):
            raise InputError(config.path, "validation.complement", "needs a holdout > 0: nothing is held out to fit on")
        fit, test = test, fit
    dataset, validation_sets = with_validation_sets(dataset, config)
    config.priors.check_names(robot.parameter_names, robot.name)
    _check_stage_names(config, robot)
    test = np.concatenate([test, *(indices for _, indices in validation_sets)]).astype(int)
    if isinstance(formulation, Combined):
        observations = formulation.observations(dataset, fit, test)
    else:
        observations = formulation.fit_observations(dataset, settings, fit)
    return Problem(
        formulation=formulation,
        settings=settings,
        dataset=dataset,
        robot=robot,
        fit=fit,
        test=test,
        candidates=tuple(candidate_parameters(robot, config.model, config.compliant_joints)),
        observations=observations,
        priors=config.priors,
        max_iterations=config.max_iterations,
        detection=detection,
        validation_sets=tuple(validation_sets),
    )


def _in_effect(measurement, dataset: Dataset):
    """The noise in effect: fgcal's defaults, what the instrument states (the dataset), what the
    config (or the set) states, the later winning."""
    return dataclasses.replace(measurement, noise=Noise.stated(dataset.noise, measurement.noise_stated))


def _check_enough(problem: Problem, state: State, candidates: list[str]) -> None:
    """At least two residuals per unknown: the candidate parameters that the stages release
    (before any is found unidentifiable, so thin data are refused rather than quietly reduced)
    and the auxiliary unknowns."""
    unknowns = len(candidates) + state.n_auxiliary
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


def _check_first_stage(problem: Problem, report: StageReport, stage: StageGraph, values) -> None:
    """Refuse to go on when the first stage leaves the typical residual (the median over the
    observations of their RMS per coordinate: a few gross misreads are the robust loss's job)
    far above both the declared noise and anything a kinematic error explains (GROSS_RESIDUAL,
    GROSS_SIGMAS); each fitting set on its own."""
    for part in problem.formulation.parts(problem):
        own = part.sets_of(stage.measurements)
        if part.use == "fit" and own:
            _check_part(part.problem, report, own[0], values, part.name)


def _check_part(problem: Problem, report: StageReport, main, values, name: str | None) -> None:
    formulation = problem.formulation
    unit = formulation.unit
    sigma = formulation.sigma(problem.settings)
    typical = float(np.median(main.unit_rms(values))) * sigma
    if typical <= GROSS_RESIDUAL[unit] or typical <= GROSS_SIGMAS * sigma:
        return
    size = f"{typical:.3g} px" if unit == "px" else f"{typical * 1e3:.4g} mm"
    raise InputError(
        problem.dataset.path,
        None,
        f"the data cannot be explained: after stage {report.name} the typical residual "
        f"{'' if name is None else f'of set {name!r} '}is {size} per "
        f"coordinate, {typical / sigma:.3g} times the declared noise and beyond any kinematic error "
        f"({GROSS_RESIDUAL[unit]:g} {unit}). No robot was written. Likely causes: {formulation.likely_causes}.",
    )


REJECTION_ROUNDS = 3


@contextmanager
def _breakdowns_named(dataset: Dataset, observations: Callable[[], Observations | None], when: str) -> Iterator[None]:
    """Where a measurement model breaks down (a point behind the camera) on the user's data:
    an error naming the configuration, whose measurements do not match its joint values."""
    try:
        yield
    except OutsideModelError as exc:
        current = observations()
        if exc.configuration is None or current is None:
            raise InputError(dataset.path, None, f"{exc} ({when})") from None
        config = current.config_ids[exc.configuration]
        fixed = dataset.camera is not None and dataset.camera_mounting is None
        raise InputError(
            dataset.path / "configurations.csv", f"configuration {config}", f"{exc} ({when}): the measurements "
            f"of {config} do not match its joint values (a joint in other units or a wrong row?)"
            + ("; dataset.yaml gives no camera.mounting: a camera fixed in the cell is the static_camera "
               "formulation's" if fixed else ""),
        ) from None  # fmt: skip


def calibrate(config: CalibrationConfig, progress: Say | None = None) -> CalibrationResult:
    """Load the config's dataset and calibrate (see :func:`calibrate_dataset`)."""
    if not (Path(config.dataset) / "dataset.yaml").is_file() and not Path(config.dataset).is_file():
        raise InputError(config.path, "dataset", f"no dataset at {config.dataset} (a folder with a dataset.yaml)")
    return calibrate_dataset(load_dataset(config.dataset), config, progress)


def calibrate_dataset(dataset: Dataset, config: CalibrationConfig, progress: Say | None = None) -> CalibrationResult:
    """Identifiability analysis, staged solving, covariances and validation on the held-out
    measurements. A simulation's truth is not read here: score the result afterwards with
    fgcal.calibration.scoring.score_with_truth."""
    say = progress or (lambda _m: None)
    if config.model == "auto" or config.compare_models:
        started, cpu = time.perf_counter(), time.process_time()
        # The motion history's model needs a history: a dataset without one compares the others.
        models = MODELS if dataset.motion_history.known().any() else tuple(m for m in MODELS if "h" not in m)
        result, table = compare_models(lambda c: calibrate_dataset(dataset, c, progress), config, say, models)
        # The times cover every model compared; the chosen model's own are kept beside them.
        timing = {
            **result.timing, "chosen_model_total_s": result.timing["total_s"],
            "chosen_model_cpu_s": result.timing["cpu_s"], "total_s": time.perf_counter() - started,
            "cpu_s": time.process_time() - cpu,
        }  # fmt: skip
        return dataclasses.replace(result, model_comparison=table, timing=timing)
    started, cpu = time.perf_counter(), time.process_time()
    problem = build_problem(dataset, config, say)
    formulation = problem.formulation
    say(
        f"calibrating {problem.robot.name}, model {config.model}, {formulation.name} formulation: "
        f"{len(problem.fit)} configurations for fitting, {len(problem.test)} held out, "
        f"{problem.n_residuals} residuals"
    )
    if config.formulation_source != "the config":
        say(f"  formulation {formulation.name}: {config.formulation_source}")
    for part in formulation.parts(problem):
        if part.name is not None:
            rows = f"{part.problem.n_residuals} residuals" if part.use == "fit" else "not fitted, scored"
            say(f"  set {part.name}: {part.formulation.name} formulation, {part.use}: {rows}")
    if problem.detection is not None:
        d = problem.detection
        say(
            f"  detection: {d.corners} corners in {d.images} images, {d.rejected_by_gate} rejected by the gate, "
            f"{len(d.skipped)} images skipped"
        )
        for cid, reason in d.skipped:
            say(f"    skipped {cid}: {reason}")
    with _breakdowns_named(dataset, lambda: problem.observations, "at the starting values or during the fit"):
        state = formulation.initial_state(problem)
        released_by_stages = releasable(problem.candidates, config.stages)
        _check_enough(problem, state, released_by_stages)
        t = time.perf_counter()
        identifiability = analyse(
            build_graph(problem, released_by_stages, state), config.min_information, problem.priors
        )
        say(
            f"  identifiability: {len(identifiability.identifiable)} of {len(released_by_stages)} released "
            f"candidates "
            f"identifiable, condition number {identifiability.condition_number:.3g} ({time.perf_counter() - t:.2f} s)"
        )
        hidden_motion = motion_warning(identifiability)
        if hidden_motion is not None:
            say(f"  warning: {hidden_motion}")
        # The mounting components the data cannot determine stay at the nominal mounting, not at
        # the hand-eye guess: the guess is noisy, and a fixed value is no estimate.
        names = problem.robot.parameter_names
        params = state.params.copy()
        nominal = problem.robot.parameter_vector()
        for name in identifiability.unidentifiable:
            if name.startswith("tool."):
                params[names.index(name)] = nominal[names.index(name)]
        state = state.with_params(params)
        stages: list[StageReport] = []
        solve_started = time.perf_counter()
        if state.n_auxiliary:
            state, report, first_stage, first_values = solve_stage(problem, "0 (auxiliary unknowns)", [], state, say)
            stages.append(report)
            _check_first_stage(problem, report, first_stage, first_values)
            first_stage.forget()
        before = state
        final_ident = identifiability
        last_stage = last_values = None
        for i, kinds in enumerate(config.stages, start=1):
            released = stage_parameters(kinds, identifiability.identifiable)
            if not released:
                say(f"  stage {i}: nothing identifiable to release ({', '.join(kinds)})")
                continue
            if last_stage is not None:
                last_stage.forget()
            state, report, last_stage, last_values = solve_stage(problem, str(i), released, state, say)
            stages.append(report)
            if len(stages) == 1:
                _check_first_stage(problem, report, last_stage, last_values)
        for _ in range(REJECTION_ROUNDS):  # again while the refit shows more: a biased fit hides some
            if last_stage is None:
                break
            outcome = formulation.reject(
                problem, last_stage.measurements, last_values, robust_scale(last_stage.measurements, last_values)
            )
            if outcome is None:
                break
            problem = problem.with_fit(*outcome)
            say(f"  rejected {len(problem.rejected)} measurements beyond 5 sigma in all; solving the last stage again")
            last_stage.forget()
            state, report, last_stage, last_values = solve_stage(
                problem, f"{len(config.stages)} (after rejection)", last_stage.released, state, say
            )
            stages.append(report)
        if last_stage is not None:
            state, last_stage, last_values, final_ident = _identifiable_at_solution(
                problem, identifiability, state, last_stage, last_values, stages, config.min_information, say
            )
    solve_time = time.perf_counter() - solve_started
    declared = joint_covariance(last_stage, last_values) if last_stage is not None else None
    released = list(last_stage.released) if last_stage is not None else []
    fit = stages[-1].fit if stages else None
    factor = fit.variance_factor if fit is not None else 1.0
    if fit is not None and not fit.consistent:
        say(f"  {fit.sentence()}")
    # The measurements' noise scaled by the fit's variance factor, the stated priors as stated.
    covariance = joint_covariance(last_stage, last_values, factor) if declared is not None else None
    evidence: dict[str, float] = {}
    fixed = [name for name in released_by_stages if name in final_ident.unidentifiable]
    if last_stage is not None and fixed:
        evidence = evidence_against_fixing(
            build_graph(problem, [*released, *fixed], state), fixed, factor, config.min_information
        )
    test_observations, flagged = formulation.test_observations(problem, state)
    measured = {}
    for label, st in (("before", before), ("after", state)):
        with _breakdowns_named(dataset, lambda: test_observations, f"held out, {label} the calibration"):
            errors = {} if test_observations is None else formulation.held_out_errors(problem, test_observations, st)
        measured[label] = {k: stats(v.errors, v.configs) for k, v in errors.items()}
    prediction = None
    if test_observations is not None and covariance is not None and released:
        prediction = formulation.predicted_held_out(problem, test_observations, state, covariance, factor)
    by_tip = measured_by_tip(problem, test_observations, before, state, covariance, factor)
    # Nothing held out: each tip's fitting residuals, before and after (a tree's chains one by one).
    fit_by_tip = None if len(problem.test) else measured_by_tip(problem, problem.observations, before, state, None, 1.0)
    residual = None
    if config.residual_model == "gp":
        t = time.perf_counter()
        residual = fit_residual_model(problem, state, test_observations)
        held = (
            "" if residual.held_out_rms_m is None
            else f"; held out against the measurements {residual.held_out_rms_m * 1e3:.4g} mm with it (predicted "
            f"{residual.predicted_rms_m * 1e3:.4g} mm), {residual.held_out_rms_without_m * 1e3:.4g} mm without"
        )  # fmt: skip
        say(
            f"  residual model (Gaussian process): cross-validated {residual.cv_rms_with_m * 1e3:.4g} mm against "
            f"{residual.cv_rms_without_m * 1e3:.4g} mm without, {'used' if residual.used else 'not used'}"
            f"{held} ({time.perf_counter() - t:.1f} s)"
        )
    references = reference_check(problem.dataset, problem.settings.noise.tracker_m)
    if references is not None:
        misreads = sum(len(t.get("misreads", [])) for t in references["targets"].values())
        say(
            f"  tracker references: common drift {references['common_drift_norm_m'] * 1e3:.3g} mm over the "
            f"session, {misreads} gross misreads"
        )
    return CalibrationResult(
        config=config,
        problem=problem,
        identifiability=identifiability,
        final_identifiability=final_ident,
        stages=tuple(stages),
        before=before,
        state=state,
        released=released,
        covariance=covariance,
        covariance_declared=declared,
        fit=fit,
        tool_point=formulation.default_tool_point(problem, state),
        test_observations=test_observations,
        flagged=tuple(flagged),
        validation=measured,
        prediction=prediction,
        measured=measured,
        measured_prediction=prediction,
        references=references,
        residual_model=residual,
        fixed_evidence_sigmas=evidence,
        by_tip=by_tip,
        fit_by_tip=fit_by_tip,
        timing={
            "solve_s": solve_time,
            "total_s": time.perf_counter() - started,
            "cpu_s": time.process_time() - cpu,
        },
    )


def _identifiable_at_solution(
    problem: Problem,
    identifiability: Identifiability,
    state: State,
    stage: StageGraph,
    values,
    stages: list[StageReport],
    min_information: float,
    say: Say,
):
    """The identifiability analysis again at the solution, on the released parameters.

    At the starting point the residuals are far above the noise, and a direction that only
    changes the residuals in proportion to themselves (a common scale of every length and
    touched point, a rotation about the vertical when compliances have gravity moments) looks
    determined there; at the solution it is not. Released parameters found unidentifiable at
    the solution are fixed at their estimates (gauge directions: any value fits as well) and the
    last stage is solved again, so that the covariance describes only what the data determine."""
    stage.forget()  # the analysis evaluates its own graph at the same point
    at_solution = analyse(build_graph(problem, stage.released, state), min_information, problem.priors)
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
        stage.forget()
        again = analyse(build_graph(problem, kept, state), min_information, problem.priors)
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


def _check_stage_names(config: CalibrationConfig, robot) -> None:
    """A parameter a stage names (alpha3, d6, a {kind, joints} entry's, a fixed one) is the
    robot's, and a fixed one is one the stage releases."""
    names = set(robot.parameter_names)
    for i, stage in enumerate(config.stages):
        for item in stage:
            name = item.removeprefix("!")
            if name in STAGE_KINDS:
                continue
            if name not in names:
                raise InputError(config.path, f"stages[{i}]", f"{robot.name} has no parameter {name!r}")
            if item.startswith("!") and not any(kind_label(name) == k or name == k for k in stage):
                raise InputError(config.path, f"stages[{i}].fix", f"{name}: the stage does not release it")


def held_out_summary(result: CalibrationResult) -> str | None:
    """One line on the held-out error before and after, or None when nothing was scored."""
    scores = [primary_score(result.validation, label) for label in ("before", "after")]
    if scores[1] is None:
        return None
    (key, before), (_, after) = scores
    predicted = f" (predicted {result.prediction.rms * 1e3:.4g} mm)" if result.prediction is not None else ""
    reference = "the simulation's truth" if result.truth is not None else "the held-out measurements"
    headline = result.problem.formulation.headline_name
    reference += "" if headline is None or result.truth is not None else f" of set {headline}"
    return (
        f"  held-out {SCORES[key]} against {reference}: before {before.rms * 1e3:.4g} mm RMS, "
        f"after {after.rms * 1e3:.4g} mm RMS{predicted}"
    )
