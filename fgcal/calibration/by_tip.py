"""Held-out figures per tip of a tree: each chain's own error before and after the calibration
and its prediction. A pooled RMS hides an arm that calibrated badly behind one that did well.

Against the held-out measurements each robust unit's tip comes from the formulation
(``Formulation.unit_tips``); against a simulation's truth, each scored point's (``Scored.tips``).
A serial arm, or a formulation that does not say, has none (None).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .prediction import scored_covariances
from .problem import JointCovariance, Observations, Prediction, Problem, prediction
from .results import ErrorStats, stats
from .state import State


@dataclass(frozen=True)
class TipScore:
    """One tip's held-out errors (m) before and after, and the prediction of after's RMS."""

    before: ErrorStats
    after: ErrorStats
    predicted: Prediction | None

    def as_dict(self) -> dict:
        return {
            "n_errors": int(self.after.errors.size),
            "before_rms_m": self.before.rms,
            "after_rms_m": self.after.rms,
            "predicted_rms_m": None if self.predicted is None else self.predicted.rms,
        }


def measured_by_tip(
    problem: Problem,
    observations: Observations | None,
    before: State,
    after: State,
    covariance: JointCovariance | None,
    factor: float,
) -> dict[str, TipScore] | None:
    """Per tip, the held-out measurements' main score (Formulation.held_out_errors) and its
    prediction (held_out_variances); None on a single tip."""
    formulation = problem.formulation
    if observations is None:
        return None
    tips = formulation.unit_tips(problem, observations)
    if tips is None or len(set(tips)) < 2:
        return None
    errors = {label: formulation.held_out_errors(problem, observations, st)[formulation.score].errors
              for label, st in (("before", before), ("after", after))}  # fmt: skip
    if any(len(e) != len(tips) for e in errors.values()):  # a score not one per unit: no split
        return None
    variances = None
    if covariance is not None and covariance.released:
        variances = formulation.held_out_variances(problem, observations, after, covariance, factor)
    return _split(np.asarray(tips, dtype=str), errors, variances, factor)


def truth_by_tip(
    problem: Problem, errors: dict[str, np.ndarray], after: State, covariance: JointCovariance | None, factor: float
) -> dict[str, TipScore] | None:
    """Per tip, the errors against the truth (``errors``: label -> scoring.truth_errors'
    main score, point-major) and their prediction (the scored points' covariances, no noise);
    None on a single tip."""
    scored = problem.formulation.scored(problem, after)
    if scored.tips is None or isinstance(problem.frame, str):
        return None
    names = np.array([problem.frame[int(t)] for t in scored.tips], dtype=str)
    if len(set(names)) < 2:
        return None
    q, motion = problem.dataset.q[problem.test], problem.dataset.motion[problem.test]
    tips = np.repeat(names, len(q))
    variances = None
    if covariance is not None and covariance.released:
        _, covariances = scored_covariances(problem, after, covariance, q, motion)
        variances = (np.trace(covariances, axis1=1, axis2=2), np.zeros(len(tips)))
    return _split(tips, errors, variances, factor)


def _split(
    tips: np.ndarray,
    errors: dict[str, np.ndarray],
    variances: tuple[np.ndarray, np.ndarray] | None,
    factor: float,
) -> dict[str, TipScore]:
    out = {}
    for tip in dict.fromkeys(tips.tolist()):  # in the order they come
        rows = tips == tip
        predicted = None if variances is None else prediction(variances[0][rows], variances[1][rows], factor)
        out[tip] = TipScore(stats(errors["before"][rows]), stats(errors["after"][rows]), predicted)
    return out
