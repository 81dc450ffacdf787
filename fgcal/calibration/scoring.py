"""Scoring against a simulation's ground truth.

Called after the calibration (``score_with_truth(result)`` returns a new result); nothing here
feeds back into the estimation. The truth (fgcal.data.truth) is evaluated with the simulator's own
full model, not the model that was fitted: a DH fit of a compliant robot is scored against the
compliant robot. The formulation says what its score measures (its scored points, with the
estimate's values and with the truth's) and which gauge the score removes first.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..data.compensation import compensate, nominal_of
from ..data.truth import Truth, load_truth
from ..model.motion import MotionHistory, features
from .by_tip import truth_by_tip
from .gauge import remove_gauge
from .prediction import predicted_against_truth, scored_covariances, scored_positions
from .problem import HeldOut, Problem
from .results import CalibrationResult, CompensationStudy, stats
from .state import State


def truth_errors(
    problem: Problem,
    state: State,
    truth: Truth,
    q: np.ndarray | None = None,
    points: np.ndarray | None = None,
    motion: np.ndarray | None = None,
) -> dict[str, HeldOut]:
    """Error vectors (m) of the formulation's scored points at the estimate ``state`` against
    the truth, on the held-out configurations as they were reached (or at ``q``, reached as
    ``motion`` says: None, no history), the score's gauge removed: the main score
    ``tool_point`` (every scored point, point-major) and each extra point's. ``points`` (k, 3)
    replace the scored points where they are constants (a camera's)."""
    true_motion = motion
    if q is None:
        q, motion = problem.dataset.q[problem.test], problem.dataset.motion[problem.test]
        # The true robot went the way the simulator took it, whatever the dataset now says.
        history = truth.history_of(problem.dataset.configs[problem.test], q)
        true_motion = features(q, history) if history is not None else motion
    if not len(q):  # nothing held out: nothing to score
        return {}
    formulation = problem.formulation
    true_robot, true_state = formulation.true_state(problem, truth)
    estimated, true = formulation.scored(problem, state), formulation.scored(problem, true_state)
    if points is not None:
        if estimated.points_from is not None:
            raise ValueError(f"the {formulation.name} formulation scores estimated points: they cannot be replaced")
        estimated, true = replace(estimated, points=points), replace(true, points=points)
    gauge = formulation.gauge(problem.settings)
    pairs = [("tool_point", estimated, true)]
    for name, point in estimated.extra.items():
        one = {"points": point[None, :], "tips": None}
        pairs.append((name, replace(estimated, **one), replace(true, **one)))
    out = {}
    for name, mine, theirs in pairs:
        predicted = scored_positions(problem.robot, problem.frame, state.params, q, motion, mine)
        reference = scored_positions(true_robot, problem.frame, true_state.params, q, true_motion, theirs)
        out[name] = HeldOut(remove_gauge(predicted, reference, gauge), np.tile(np.arange(len(q)), len(mine.points)))
    return out


def score_with_truth(result: CalibrationResult) -> CalibrationResult:
    """The result scored against its simulation's truth, if the dataset has one: the held-out
    scores (before and after) and their prediction are then against the truth, and the report
    shows the true parameters. Without a truth, the result as it was."""
    problem = result.problem
    truth = load_truth(problem.dataset.path)
    if truth is None:
        return result
    for path in result.config.validation_datasets:
        # A validation set is scored against the truth only when it measured the same true robot.
        other = load_truth(path)
        if other is None or other.parameters != truth.parameters:
            return result
    errors = {label: truth_errors(problem, state, truth) for label, state in (("before", result.before),
                                                                               ("after", result.state))}  # fmt: skip
    validation = {label: {k: stats(v.errors, v.configs) for k, v in found.items()} for label, found in errors.items()}
    factor = result.fit.variance_factor if result.fit is not None else 1.0
    by_tip = None
    if all("tool_point" in found for found in errors.values()):
        main = {label: found["tool_point"].errors for label, found in errors.items()}
        by_tip = truth_by_tip(problem, main, result.state, result.covariance, factor)
    prediction = None
    if result.covariance is not None:
        test = problem.test
        prediction = predicted_against_truth(
            problem, result.state, result.covariance, problem.dataset.q[test], problem.dataset.motion[test], factor
        )
    return replace(
        result,
        truth=truth,
        validation=validation,
        prediction=prediction,
        gauge=problem.formulation.gauge(problem.settings),
        by_tip=by_tip,
    )


CHI2_3_95 = 7.814727903251178  # 95 % quantile of chi-square with 3 degrees of freedom


def position_coverage(result: CalibrationResult) -> float:
    """Fraction of the held-out scored points whose true error (gauge removed: truth_errors)
    lies inside the 95 % ellipsoid of its predicted covariance; needs the truth."""
    problem = result.problem
    truth = result.truth if result.truth is not None else load_truth(problem.dataset.path)
    error = truth_errors(problem, result.state, truth)["tool_point"].errors
    test = problem.test
    _, covariances = scored_covariances(
        problem, result.state, result.covariance, problem.dataset.q[test], problem.dataset.motion[test]
    )
    # Pseudo-inverse: removing the gauge leaves each 3x3 block full rank here, but not by design.
    d2 = np.einsum("ni,nij,nj->n", error, np.linalg.pinv(covariances), error)
    return float(np.mean(d2 <= CHI2_3_95))


def compensation_study(result: CalibrationResult, n_targets: int = 200, seed: int = 0) -> CompensationStudy:
    """Compensation scored on the simulated true robot (fgcal.data.compensation): ``n_targets``
    random targets for the first scored point (its position at the dataset's configurations
    moved by up to 0.1 rad per joint, seeded), each from a hint 0.05 rad off. Compensated: the
    joints at which the calibrated model reaches the target; uncompensated: the joints the
    controller's nominal model finds for it. Both are driven through the true robot, target
    after target in their order (a robot with lost motion reaches each from the one before),
    and compared with the target in the score's frame, the score's gauge removed (SI). With a
    model that has the motion terms, the commands allow for that approach, and the RMS of
    commands that do not is given too."""
    problem = result.problem
    truth = result.truth if result.truth is not None else load_truth(problem.dataset.path)
    formulation = problem.formulation
    robot = problem.robot  # with the result's model
    params = robot.parameter_dict(result.state.params)
    rng = np.random.default_rng(seed)
    q_data = problem.dataset.q[rng.integers(0, len(problem.dataset.q), n_targets)]
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q_target = np.clip(q_data + rng.uniform(-0.1, 0.1, q_data.shape), low, high)
    estimated = formulation.scored(problem, result.state)
    frame = problem.scored_frame(result.state)
    first = replace(estimated, points=estimated.points[:1], tips=None)
    tcp = first.points[0]
    targets = scored_positions(robot, frame, result.state.params, q_target, None, replace(first, instrument=None))
    hints = np.clip(q_target + rng.normal(0.0, 0.05, q_target.shape), low, high)
    nominal = nominal_of(problem.dataset.robot, None)
    approach = np.full(q_target.shape, np.nan) if robot.history else None
    solved = compensate(replace(robot, overrides=params), nominal, targets, hints, tcp, frame, approach=approach)
    controller = nominal.ik(targets, hints, tcp=tcp, frame=frame)
    usable = np.isin(solved.status, ("ok", "near singularity")) & np.isin(controller.status, ("ok", "near singularity"))
    true_robot, true_state = formulation.true_state(problem, truth)
    true = formulation.scored(problem, true_state)
    true = replace(true, points=true.points[:1], tips=None)
    wanted = scored_positions(robot, frame, result.state.params, q_target[usable], None, first)
    gauge = formulation.gauge(problem.settings)

    def landed(q: np.ndarray) -> np.ndarray:
        """Where the true robot lands under the commands q (all targets, in order)."""
        motion = features(q, MotionHistory.in_order(q))[usable]
        return remove_gauge(
            scored_positions(true_robot, frame, true_state.params, q[usable], motion, true), wanted, gauge
        )

    without = None
    if solved.motion_offset is not None:
        without = stats(landed(solved.q + solved.motion_offset)).rms

    return CompensationStudy(
        n_targets=int(n_targets),
        n_scored=int(usable.sum()),
        status={s: int(np.sum(solved.status == s)) for s in sorted(set(solved.status.tolist()))},
        model_residual_max_m=float(solved.residual_m[usable].max()),
        compensated_rms_m=stats(landed(solved.q)).rms,
        uncompensated_rms_m=stats(landed(controller.q)).rms,
        gauge_removed=gauge,
        seed=seed,
        without_approach_rms_m=without,
    )
