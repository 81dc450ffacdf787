"""What a calibration returns: typed, constant results (SI). The pipeline builds them; scoring
against a simulation's truth and the compensation study return new ones; reports only read."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ..data.truth import Truth
from .config import CalibrationConfig
from .goodness import Fit, goodness_of_fit
from .identifiability import Identifiability
from .problem import JointCovariance, Observations, Prediction, Problem
from .residual_model import ResidualModelResult
from .state import State


@dataclass(frozen=True)
class StageReport:
    name: str
    released: list[str]
    residual_norm: float  # sqrt(sum of squared whitened measurement residuals)
    residual_rms: Mapping[str, float]  # RMS of the measurement residuals per unit of the rows (m, rad, px)
    iterations: int
    time_s: float  # wall
    cpu_s: float
    n_unknowns: int = 0  # released parameters and auxiliary unknowns (tangent dimensions)
    n_residuals: int = 0  # measurement residuals the stage fitted

    @property
    def fit(self) -> Fit:
        return goodness_of_fit(self.residual_norm**2, self.n_residuals, self.n_unknowns)

    def rms_text(self) -> str:
        """The residual RMS in the units an engineer reads (mm, mrad, px)."""
        scale = {"m": (1e3, "mm"), "rad": (1e3, "mrad"), "px": (1.0, "px")}
        return ", ".join(f"{v * scale[u][0]:.4g} {scale[u][1]}" for u, v in self.residual_rms.items())


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of held-out errors (norms), with the configuration of each error (index into
    the scored observations' config_ids) and, where the errors are vectors, the RMS per axis."""

    mean: float
    rms: float
    max: float
    errors: np.ndarray  # norms
    axis_rms: np.ndarray | None = None  # (3,) where there are vectors
    configs: np.ndarray | None = None
    vectors: np.ndarray | None = None  # (N, 3) the error vectors, where the score has them

    def as_dict(self) -> dict:
        if not self.errors.size:
            return {"mean": None, "rms": None, "p50": None, "p95": None, "max": None}
        p50, p95 = np.percentile(self.errors, [50, 95])
        out = {"mean": self.mean, "rms": self.rms, "p50": float(p50), "p95": float(p95), "max": self.max}
        if self.axis_rms is not None:
            out.update({f"rms_{axis}": float(v) for axis, v in zip("xyz", self.axis_rms, strict=True)})
        return out


def stats(errors: np.ndarray, configs: np.ndarray | None = None) -> ErrorStats:
    """Statistics of error norms (N,) or of error vectors (N, 3), whose norms they then use
    and whose RMS per axis they add."""
    errors = np.asarray(errors, dtype=float)
    if errors.size == 0:
        return ErrorStats(math.nan, math.nan, math.nan, np.zeros(0))
    axis_rms = vectors = None
    if errors.ndim == 2:
        axis_rms = np.sqrt(np.mean(errors**2, axis=0))
        vectors = errors
        errors = np.linalg.norm(errors, axis=1)
    return ErrorStats(
        float(errors.mean()), float(np.sqrt(np.mean(errors**2))), float(errors.max()), errors, axis_rms, configs,
        vectors,
    )  # fmt: skip


# Held-out scores, in order of preference, with their label (all in m).
SCORES = {
    "tool_point": "position error",
    "distance": "distance error",
    "contact": "contact error",
    "point_pair": "point-pair error",
    "reprojection": "reprojection error",
}


def primary_score(validation: Mapping, label: str) -> tuple[str, ErrorStats] | None:
    """The main held-out score of ``label`` ('before' or 'after'): the positioning error where
    there is one (truth, tracker), else the held-out point pairs, distances, reprojections."""
    scores = validation.get(label, {})
    for key in SCORES:
        if key in scores and scores[key].errors.size:
            return key, scores[key]
    return None


@dataclass(frozen=True)
class CompensationStudy:
    """Compensation scored on a simulated true robot (fgcal.calibration.scoring)."""

    n_targets: int
    n_scored: int
    status: dict[str, int]
    model_residual_max_m: float
    compensated_rms_m: float
    uncompensated_rms_m: float
    gauge_removed: str
    seed: int
    # With a robot calibrated with lost motion: the compensated RMS when the commands do not
    # allow for the approach (None: the robot has no motion terms).
    without_approach_rms_m: float | None = None

    @property
    def improvement(self) -> float:
        return self.uncompensated_rms_m / self.compensated_rms_m

    def as_dict(self) -> dict:
        return {
            "n_targets": self.n_targets,
            "n_scored": self.n_scored,
            "status": dict(self.status),
            "model_residual_max_m": self.model_residual_max_m,
            "compensated_rms_m": self.compensated_rms_m,
            "uncompensated_rms_m": self.uncompensated_rms_m,
            "improvement": self.improvement,
            "gauge_removed": self.gauge_removed,
            "seed": self.seed,
            "without_approach_rms_m": self.without_approach_rms_m,
        }


@dataclass(frozen=True)
class ModelRow:
    """One model of a model comparison (fgcal.calibration.models)."""

    model: str
    n_unknowns: int
    chi2_per_dof: float
    held_out_rms_m: float | None
    aic: float
    bic: float
    time_s: float
    supported: bool = False

    def as_dict(self) -> dict:
        return {
            "model": self.model,
            "n_unknowns": self.n_unknowns,
            "chi2_per_dof": self.chi2_per_dof,
            "held_out_rms_m": self.held_out_rms_m,
            "aic": self.aic,
            "bic": self.bic,
            "time_s": self.time_s,
            "supported": self.supported,
        }


@dataclass(frozen=True)
class CalibrationResult:
    config: CalibrationConfig
    problem: Problem  # after outlier rejection (its fitting observations and rejection records)
    identifiability: Identifiability  # at the start
    final_identifiability: Identifiability  # at the solution
    stages: tuple[StageReport, ...]
    before: State  # after the auxiliary unknowns' stage, before any parameter moved
    state: State
    released: list[str]
    covariance: JointCovariance | None  # (P, auxiliary unknowns), scaled by the fit's variance factor
    covariance_declared: JointCovariance | None  # under the declared noise, unscaled
    fit: Fit | None  # goodness of fit of the last stage
    tool_point: np.ndarray  # the scored point, in the formulation's frame (m)
    test_observations: Observations | None
    flagged: tuple = ()  # held-out measurements left out of the score as gross errors (problem.Rejection)
    # Held-out scores, 'before' and 'after' -> score name -> stats: against the truth once
    # scored with it (fgcal.calibration.scoring), else against the held-out measurements.
    validation: Mapping[str, Mapping[str, ErrorStats]] = field(default_factory=dict)
    prediction: Prediction | None = None  # of validation's primary score
    measured: Mapping[str, Mapping[str, ErrorStats]] = field(default_factory=dict)  # always the measurements'
    measured_prediction: Prediction | None = None
    truth: Truth | None = None
    gauge: str = "none"  # removed before validation's scores
    compensation: CompensationStudy | None = None
    model_comparison: tuple[ModelRow, ...] | None = None
    references: dict | None = None  # the tracker's stability (calibration.references)
    residual_model: ResidualModelResult | None = None  # residual_model: gp
    # Parameters the stages release but identifiability fixed -> how many sigmas a fit releasing
    # each would move it (calibration.identifiability.evidence_against_fixing)
    fixed_evidence_sigmas: Mapping[str, float] = field(default_factory=dict)
    # A tree's held-out figures per tip (fgcal.calibration.by_tip.TipScore), as validation is:
    # against the truth once scored with it, else the measurements'; None on a serial arm.
    by_tip: Mapping[str, object] | None = None
    # With nothing held out, a tree's fitting residuals per tip (TipScore: before and after the
    # calibration, no prediction); None otherwise.
    fit_by_tip: Mapping[str, object] | None = None
    # k-fold cross-validation (calibration.cross_validation): per fold and pooled; validation and
    # prediction then hold the folds' pooled errors, and this result is the fit on all.
    cross_validation: Mapping[str, object] | None = None
    timing: Mapping[str, float] = field(default_factory=dict)

    @property
    def formulation(self):
        return self.problem.formulation

    @property
    def held_from_earlier_stages(self) -> dict[str, str]:
        """Parameters a stage before the last moved and the last did not release (nor found not
        identifiable at the solution: those are reported with their reason) -> the name of the
        last stage that estimated them: held at that value, their uncertainty in no sigma and
        no prediction."""
        final = set(self.released) | set(self.final_identifiability.unidentifiable)
        out: dict[str, str] = {}
        for stage in self.stages[:-1]:
            for name in stage.released:
                if name not in final:
                    out[name] = stage.name
        return out

    @property
    def sigmas(self) -> dict[str, float]:
        """Sigma of each released parameter (SI), scaled by the fit's variance factor."""
        if self.covariance is None:
            return {}
        return dict(zip(self.released, map(float, self.covariance.sigmas("P")), strict=True))

    @property
    def parameters(self) -> dict[str, float]:
        """Every parameter of the robot at the estimate (SI)."""
        return self.problem.robot.parameter_dict(self.state.params)

    @property
    def parameter_covariance(self) -> np.ndarray:
        """Covariance of the released parameters (SI), in ``released`` order."""
        if self.covariance is None or not self.released:
            return np.zeros((0, 0))
        return self.covariance.block(["P"])
