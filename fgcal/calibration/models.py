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
from collections.abc import Callable
from dataclasses import replace

from ..robot import MODELS


def compare_models(calibrate_one: Callable, config, say: Callable[[str], None]) -> tuple[object, list[dict]]:
    """Calibrate with each model; returns the result of the one with the lowest BIC and the
    comparison table (one dict per model, SI)."""
    results, table = {}, []
    for model in MODELS:
        say(f"model comparison: {model}")
        result = calibrate_one(replace(config, model=model, compare_models=False))
        results[model] = result
        fit = result.fit
        n = result.problem.n_residuals
        k = len(result.released) + result.state.n_auxiliary
        log_term = n * math.log(max(fit.chi2, 1e-300) / n)
        scored = result.validation.get("after", {})
        held_out = next((stats.rms for stats in scored.values() if stats.errors.size), None)
        table.append(
            {
                "model": model,
                "n_unknowns": k,
                "chi2_per_dof": fit.chi2_per_dof,
                "held_out_rms_m": held_out,
                "aic": log_term + 2 * k,
                "bic": log_term + k * math.log(n),
            }
        )
    best = min(table, key=lambda row: row["bic"])["model"]
    for row in table:
        row["supported"] = row["model"] == best
    say(f"model comparison: the data support {best} (lowest BIC)")
    return results[best], table
