"""Model choice: DH, DH,s and DH,s,e fitted to the same data and compared.

Each model is calibrated with the same config. The comparison gives, per model, the number of
estimated unknowns k, chi2/dof, the held-out error and the information criteria with the noise
level estimated from the data (sigma unknown: the declared one may be wrong, as on the FARO
set), n the residual count:

    AIC = n ln(chi2/n) + 2k        BIC = n ln(chi2/n) + k ln n

The data support the model with the lowest BIC (the stricter of the two about extra
parameters); ``model: auto`` calibrates with it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace

from ..model.robot import MODELS
from .config import CalibrationConfig
from .results import CalibrationResult, ModelRow, primary_score


def compare_models(
    calibrate_one: Callable[[CalibrationConfig], CalibrationResult],
    config: CalibrationConfig,
    say: Callable[[str], None],
    models: tuple[str, ...] = MODELS,
) -> tuple[CalibrationResult, tuple[ModelRow, ...]]:
    """Calibrate with each of ``models``; returns the result of the one with the lowest BIC and
    the comparison table (one row per model, SI)."""
    results, rows = {}, []
    for model in models:
        say(f"model comparison: {model}")
        started = time.perf_counter()
        result = calibrate_one(replace(config, model=model, compare_models=False))
        results[model] = result
        fit = result.fit
        n = result.problem.n_residuals
        k = len(result.released) + result.state.n_auxiliary
        log_term = n * math.log(max(fit.chi2, 1e-300) / n)
        scored = primary_score(result.validation, "after")
        rows.append(
            ModelRow(
                model=model,
                n_unknowns=k,
                chi2_per_dof=fit.chi2_per_dof,
                held_out_rms_m=scored[1].rms if scored is not None else None,
                aic=log_term + 2 * k,
                bic=log_term + k * math.log(n),
                time_s=time.perf_counter() - started,
            )
        )
    best = min(rows, key=lambda row: row.bic).model
    say(f"model comparison: the data support {best} (lowest BIC)")
    return results[best], tuple(replace(row, supported=row.model == best) for row in rows)
