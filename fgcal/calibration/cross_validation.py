"""k-fold cross-validation (``validation: {folds: k, seed: s}``): each fold held out of a fit on
the other folds, exactly the run ``validation: {folds: k, fold: i, seed: s}`` gives; the held-out
errors and their predictions pooled over the folds; the calibration reported is the fit on every
configuration (nothing held out: the folds say how well such a fit holds out)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from .config import CalibrationConfig
from .problem import Prediction
from .results import CalibrationResult, ErrorStats, primary_score, stats


def cross_validate(
    config: CalibrationConfig,
    calibrate: Callable[[CalibrationConfig], CalibrationResult],
    say: Callable[[str], None] = lambda _: None,
) -> CalibrationResult:
    """The fit on all configurations, its ``validation`` and ``prediction`` the folds' pooled
    (``cross_validation``: per fold and pooled, m). ``calibrate`` runs and scores one config."""
    folds = []
    for k in range(1, config.folds + 1):
        say(f"fold {k} of {config.folds}: held out of a fit on the others")
        folds.append(calibrate(dataclasses.replace(config, fold=k)))
    say(f"the fit on all configurations (the {config.folds} folds pooled above score it)")
    final = calibrate(dataclasses.replace(config, folds=None, fold=None, holdout=0.0))
    return pooled(final, folds, config)


def pooled(final: CalibrationResult, folds: list[CalibrationResult], config: CalibrationConfig) -> CalibrationResult:
    validation = {
        label: {key: _pool([f.validation[label][key] for f in folds]) for key in folds[0].validation.get(label, {})}
        for label in ("before", "after")
    }
    rows = []
    for k, result in enumerate(folds, 1):
        after, before = primary_score(result.validation, "after"), primary_score(result.validation, "before")
        rows.append({
            "fold": k, "n_held_out": len(result.problem.test),
            "before_rms_m": before[1].rms if before else None, "after_rms_m": after[1].rms if after else None,
            "predicted_rms_m": result.prediction.rms if result.prediction is not None else None,
        })  # fmt: skip
    prediction = _pool_predictions([f.prediction for f in folds], [r["n_held_out"] for r in rows])
    after = primary_score(validation, "after")
    summary = {
        "folds": config.folds,
        "order": "the run's order" if config.split == "ordered" else f"random, seed {config.split_seed}",
        "per_fold": rows,
        "pooled_after_rms_m": after[1].rms if after else None,
        "pooled_predicted_rms_m": prediction.rms if prediction is not None else None,
        "n_held_out": int(sum(r["n_held_out"] for r in rows)),
    }
    return dataclasses.replace(final, validation=validation, prediction=prediction, cross_validation=summary,
                               by_tip=_pool_tips(folds), fit_by_tip=None)  # fmt: skip


def _pool_tips(folds: list[CalibrationResult]) -> dict | None:
    """A tree's per-tip held-out figures pooled over the folds, as the pooled ones are."""
    from .by_tip import TipScore

    if not all(f.by_tip for f in folds):
        return None
    out = {}
    for tip in folds[0].by_tip:
        scores = [f.by_tip[tip] for f in folds]
        counts = [s.after.errors.size for s in scores]
        out[tip] = TipScore(_pool([s.before for s in scores]), _pool([s.after for s in scores]),
                            _pool_predictions([s.predicted for s in scores], counts))  # fmt: skip
    return out


def _pool(parts: list[ErrorStats]) -> ErrorStats:
    if all(p.vectors is not None for p in parts):
        return stats(np.concatenate([p.vectors for p in parts]))
    return stats(np.concatenate([p.errors for p in parts]))


def _pool_predictions(predictions: list[Prediction | None], counts: list[int]) -> Prediction | None:
    """The folds' predicted RMS pooled as their errors are: the mean square over every held-out
    configuration."""
    if any(p is None for p in predictions) or not sum(counts):
        return None
    weights = np.array(counts, dtype=float) / sum(counts)

    def mean_square(values) -> float:
        return float(np.sqrt(np.sum(weights * np.square(values))))

    return Prediction(
        mean_square([p.rms for p in predictions]),
        mean_square([p.parameters_rms for p in predictions]),
        mean_square([p.noise_rms for p in predictions]),
        float(np.sum(weights * [p.variance_factor for p in predictions])),
    )
