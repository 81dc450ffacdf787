"""The optional residual model (``residual_model: gp``): what the kinematic model leaves, learned
as a function of the configuration and how it was reached, and kept only where it wins.

After the calibration, each fitting configuration's mean residual (over its measured points,
3-vector in the score's frame, m) is regressed on its joint values and motion-history features
(fgcal.model.motion) by a Gaussian process (scikit-learn: an amplitude times an RBF kernel with one
length scale per input, plus white noise; hyperparameters by maximum likelihood). Whether it
wins is decided on the fitting data alone, by K-fold cross-validation, the hyperparameters fitted
again in each fold from the same start (never from the whole fit's, which saw the fold): it
wins when the configurations' squared errors shrink by more than twice the standard error of
their mean change (a paired comparison, one value per configuration). The held-out
configurations are then scored with and without the correction.

The predicted held-out RMS with the correction: per scored point, the GP's predictive variance
of its configuration's mean (noise included, three coordinates) plus the scatter of points about
their configuration's mean in the fitting data.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from .problem import Observations, Problem
from .state import State

SKLEARN_MISSING = "needs scikit-learn: pip install '.[residual]' in fgcal's folder (or pip install scikit-learn)"
FOLDS = 5
SEED = 0  # of the folds and the optimiser's restarts


@dataclass(frozen=True)
class ResidualModelResult:
    """What the residual model did (SI): whether it is used, the cross-validated RMS of the
    fitting points with and without it, and the held-out RMS with it and its prediction."""

    used: bool
    kernel: str
    cv_rms_without_m: float
    cv_rms_with_m: float
    held_out_rms_without_m: float | None
    held_out_rms_m: float | None
    predicted_rms_m: float | None
    n_train: int
    seed: int = SEED

    def as_dict(self) -> dict:
        return {
            "kind": "gp",
            "used": self.used,
            "kernel": self.kernel,
            "cv_rms_without_m": self.cv_rms_without_m,
            "cv_rms_with_m": self.cv_rms_with_m,
            "held_out_rms_without_m": self.held_out_rms_without_m,
            "held_out_rms_m": self.held_out_rms_m,
            "predicted_rms_m": self.predicted_rms_m,
            "n_train_configurations": self.n_train,
            "folds": FOLDS,
            "seed": self.seed,
        }


def check_residual_model(formulation, source) -> None:
    """The residual model needs a score that is a point's error vector, and scikit-learn:
    checked before the calibration, not after it."""
    import importlib.util

    if importlib.util.find_spec("sklearn") is None:
        raise InputError(source, "residual_model", SKLEARN_MISSING)
    if not formulation.score_vectors:
        raise InputError(
            source, "residual_model",
            f"the {formulation.name} formulation's score is not a point's error vector: the residual model needs "
            "one (tracker, touch or poses)",
        )  # fmt: skip


def _inputs(problem: Problem, observations: Observations) -> np.ndarray:
    """Per configuration of the observations: joint values and motion features."""
    motion = problem.dataset.motion_of(observations.config_ids)
    return np.hstack([observations.q, motion])


def _per_configuration(errors: np.ndarray, configs: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean error vector (n, 3) of each configuration and which have any."""
    sums = np.zeros((n, 3))
    counts = np.zeros(n)
    np.add.at(sums, configs, errors)
    np.add.at(counts, configs, 1.0)
    present = counts > 0
    sums[present] /= counts[present, None]
    return sums, present


def _regressor(n_inputs: int):
    try:
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
    except ImportError:
        raise InputError(None, "residual_model", SKLEARN_MISSING) from None
    kernel = ConstantKernel(1e-8, (1e-14, 1e-2)) * RBF(np.ones(n_inputs), (1e-2, 1e3)) + WhiteKernel(
        1e-8, (1e-14, 1e-2)
    )
    return GaussianProcessRegressor(kernel=kernel, normalize_y=False, random_state=SEED, n_restarts_optimizer=0)


def fit_residual_model(problem: Problem, state: State, test_observations: Observations | None) -> ResidualModelResult:
    """Fit, cross-validate and score the residual model of a calibration whose score is a
    3-vector per measured point (tracker points, touch points, poses' positions)."""
    formulation = problem.formulation
    check_residual_model(formulation, problem.settings.source)
    observations = problem.observations
    train = formulation.held_out_errors(problem, observations, state)[formulation.score]
    n_configs = len(observations.config_ids)
    means, present = _per_configuration(train.errors, train.configs, n_configs)
    X = _inputs(problem, observations)[present]
    Y = means[present]
    scatter = train.errors - means[train.configs]  # points about their configuration's mean
    scatter2 = float(np.mean(np.sum(scatter**2, axis=1)))
    with warnings.catch_warnings():
        # A length scale at its bound is an input the residual does not depend on: an answer.
        warnings.simplefilter("ignore", category=UserWarning)
        gp = _regressor(X.shape[1]).fit(X, Y)
    # Cross-validation on the fitting configurations: the GP, hyperparameters included, fitted
    # again without each fold and scored on it.
    folds = np.random.default_rng(SEED).permutation(len(X)) % FOLDS
    configs_present = np.flatnonzero(present)
    where = {c: k for k, c in enumerate(configs_present)}
    point_fold = np.array([folds[where[c]] for c in train.configs])
    corrected = train.errors.copy()
    for fold in range(FOLDS):
        held = folds == fold
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", category=UserWarning)
            model = _regressor(X.shape[1]).fit(X[~held], Y[~held])
        predicted = model.predict(X[held])
        rows = point_fold == fold
        lookup = {c: k for k, c in enumerate(configs_present[held])}
        corrected[rows] -= predicted[[lookup[c] for c in train.configs[rows]]]
    cv_without = float(np.sqrt(np.mean(np.sum(train.errors**2, axis=1))))
    cv_with = float(np.sqrt(np.mean(np.sum(corrected**2, axis=1))))
    # One paired value per configuration: its points share its correction.
    per_point = np.sum(train.errors**2, axis=1) - np.sum(corrected**2, axis=1)
    gain = np.bincount(train.configs, weights=per_point, minlength=n_configs)[present]
    wins = bool(gain.mean() > 2.0 * gain.std(ddof=1) / np.sqrt(len(gain)))
    held_without = held_with = predicted_rms = None
    if test_observations is not None:
        test = formulation.held_out_errors(problem, test_observations, state)[formulation.score]
        X_test = _inputs(problem, test_observations)[test.configs]
        mean, std = gp.predict(X_test, return_std=True)
        held_without = float(np.sqrt(np.mean(np.sum(test.errors**2, axis=1))))
        held_with = float(np.sqrt(np.mean(np.sum((test.errors - mean) ** 2, axis=1))))
        # One kernel for the three coordinates: older scikit-learn gives one std per sample.
        variance = std**2 if std.ndim == 2 else np.repeat(std[:, None] ** 2, 3, axis=1)
        predicted_rms = float(np.sqrt(np.mean(np.sum(variance, axis=1)) + scatter2))
    return ResidualModelResult(
        used=wins,
        kernel=str(gp.kernel_),
        cv_rms_without_m=cv_without,
        cv_rms_with_m=cv_with,
        held_out_rms_without_m=held_without,
        held_out_rms_m=held_with,
        predicted_rms_m=predicted_rms,
        n_train=int(present.sum()),
    )
