"""The verdict at a glance: the headline of a calibration report, its worst held-out
configurations, and position accuracy and repeatability in the manner of ISO 9283.

All figures are computed from the result's held-out scores (against the truth of a simulation,
else against the held-out measurements), in SI in report.json; report.md shows mm and mdeg.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calibration.blind_spots import describe
from ..calibration.identifiability import EVIDENCE_SIGMAS
from ..calibration.results import SCORES, CalibrationResult, ErrorStats, primary_score
from ..calibration.set_report import noise_ratios

WORST = 10  # held-out configurations the report lists


def figure(value: float) -> str:
    """A figure with four significant digits, trailing zeros kept (4.000, not 4; 0.02188)."""
    return f"{value:#.4g}".rstrip(".")


def _triple(stat: ErrorStats) -> dict[str, float]:
    return {"rms": stat.rms, "p95": float(np.percentile(stat.errors, 95)), "max": stat.max}


# The declared noise and the residuals may differ by this factor before the headline says so:
# beyond it the noise, or the units it was read in, is wrong (a 0.05 mm sigma read as 50 mm).
NOISE_MISMATCH = 10.0


def validation_protocol(result: CalibrationResult) -> dict:
    """How the held-out configurations were chosen: a random split (its fraction and seed), the
    run's last part (``split: ordered``), the complement of a split, separate validation sets, or
    none; with the number of held-out configurations and a phrase for the headline."""
    config, problem = result.config, result.problem
    cv = result.cross_validation
    if cv is not None:
        return {
            "kind": f"{cv['folds']}-fold cross-validation",
            "holdout_fraction": None,
            "seed": config.split_seed if config.split != "ordered" else None,
            "validation_datasets": [],
            "n_held_out": cv["n_held_out"],
            "text": f"{cv['n_held_out']} in {cv['folds']} folds ({cv['order']}), each held out of a fit on the "
            "others, the errors pooled; the calibration reported is the fit on all configurations",
        }
    n_sets = sum(len(indices) for _, indices in problem.validation_sets)
    own = len(problem.test) - n_sets
    parts, kinds = [], []
    if own:
        if config.folds is not None and config.fold is not None:
            order = "the run's order" if config.split == "ordered" else f"random, seed {config.split_seed}"
            kind, words = f"fold {config.fold} of {config.folds}", (
                f"{own}: fold {config.fold} of {config.folds} ({order}), held out of a fit on the others"
            )  # fmt: skip
        elif config.complement:  # the split's two parts swapped: fitted on the part it holds out
            kind = f"{config.split} complement"
            part = (
                f"the run's last {config.holdout:.0%}" if config.split == "ordered"
                else f"{config.holdout:.0%} drawn at random with seed {config.split_seed}"
            )  # fmt: skip
            words = f"{own}: the complement of a split, fitted on {part}"
        elif config.split == "ordered":
            kind, words = "ordered", f"{own}: the run's last {config.holdout:.0%}, split: ordered"
        else:
            kind, words = "random", f"{own} drawn at random, {config.holdout:.0%} with seed {config.split_seed}"
        kinds.append(kind)
        parts.append(words)
    if n_sets:
        kinds.append("separate set")
        names = ", ".join(Path(path).name for path, _ in problem.validation_sets)
        parts.append(f"{n_sets} from separate validation sets ({names})")
    return {
        "kind": " + ".join(kinds) or "none",
        "holdout_fraction": config.holdout,
        "seed": config.split_seed if own and config.split != "ordered" else None,
        "validation_datasets": [str(path) for path, _ in problem.validation_sets],
        "n_held_out": len(problem.test),
        "text": "; ".join(parts) or "nothing held out",
    }


def warnings(result: CalibrationResult) -> list[str]:
    """What the headline must say before any figure is trusted: declared noise and residuals
    that differ by more than NOISE_MISMATCH, with the units of both and where the config's
    units came from."""
    out = []
    fit, problem, config = result.fit, result.problem, result.config
    by_set = noise_ratios(result)  # several measurement sets: each against its own noise, below
    if fit is not None and fit.dof > 0 and result.stages and not by_set:
        ratio = float(np.sqrt(fit.chi2_per_dof))
        if not 1 / NOISE_MISMATCH <= ratio <= NOISE_MISMATCH:
            unit = problem.formulation.unit
            scale, shown = (1e3, "mm") if unit == "m" else (1.0, unit)
            sigma = problem.formulation.sigma(problem.settings) * scale
            rms = result.stages[-1].residual_rms.get(unit, float("nan")) * scale
            side = "larger" if ratio > 1 else "smaller"
            out.append(
                f"the residuals ({figure(rms)} {shown} RMS) are {max(ratio, 1 / ratio):.3g} times {side} than the "
                "declared noise "
                f"({figure(sigma)} {shown} per row); the config's lengths are read in {config.units.length} and its "
                f"angles in {config.units.angle} ({config.units_source}): check noise: and units:; every "
                "sigma and prediction of this report depends on them"
            )
    for name, ratio in by_set.items():
        if not 1 / NOISE_MISMATCH <= ratio <= NOISE_MISMATCH:
            side = "larger" if ratio > 1 else "smaller"
            out.append(f"set {name}'s residuals are {max(ratio, 1 / ratio):.3g} times {side} than its declared noise: "
                       f"check its noise: and the units ({config.units.length}, {config.units.angle})")  # fmt: skip
    # Not a parameter the auxiliary unknowns take whole at the start (a base tilt under the
    # tracker's pose): what moves it at the solution is the gravity direction the estimated
    # compliances turn, a model effect report.json keeps (moved_if_released_sigmas), not a
    # choice the user can act on.
    reasons = result.identifiability.unidentifiable
    against = sorted(
        (
            (name, sigmas) for name, sigmas in result.fixed_evidence_sigmas.items()
            if sigmas > EVIDENCE_SIGMAS and not reasons.get(name, "").startswith(("absorbed by", "no effect"))
        ),
        key=lambda item: -item[1],
    )  # fmt: skip
    predicted = predicted_sigma(result)
    if predicted is not None and "warning" in predicted:  # an accuracy not to sign as predicted
        out.append(predicted["warning"])
    if predicted is not None and "assumption" in predicted:
        out.append(predicted["assumption"])
    if predicted is not None and "noise_warning" in predicted:
        out.append(predicted["noise_warning"])
    formulation = problem.formulation
    unread = sorted(config.stated_options - set(formulation.settings_read) - {f"robust.{formulation.kind}"})
    if unread:
        out.append(
            f"the config states settings the {formulation.name} formulation does not read: {', '.join(unread)}; "
            "they have no effect on this calibration (another formulation's, or a typo of one)"
        )
    held = result.held_from_earlier_stages
    if held:
        listed = ", ".join(f"{name} (stage {k})" for name, k in list(held.items())[:6])
        more = f" and {len(held) - 6} more" if len(held) > 6 else ""
        out.append(
            f"{_count(len(held), 'parameter')} estimated in an earlier stage and held there by the last one, which "
            f"does not release them (or fixes them): {listed}{more}; their uncertainty is in no sigma and no predicted "
            "accuracy of this report (release them in the last stage)"
        )
    if against:
        listed = ", ".join(f"{name} ({sigmas:.3g} sigma)" for name, sigmas in against[:6])
        more = f" and {len(against) - 6} more" if len(against) > 6 else ""
        out.append(
            f"{len(against)} parameters are fixed as not identifiable, but a fit releasing each would move it by "
            f"more than {EVIDENCE_SIGMAS:g} sigma: {listed}{more}; the data determine them and the calibration is "
            "worse than they support (a declared noise too large, or a stage that does not release them; "
            "report.json parameters.*.moved_if_released_sigmas)"
        )
    return out


def headline(result: CalibrationResult) -> dict | None:
    """The held-out accuracy after and before (RMS, P95 and max, m; orientation in rad where it
    is measured), the number of held-out configurations, and the sentence report.md opens with."""
    after, before = primary_score(result.validation, "after"), primary_score(result.validation, "before")
    if after is None:
        return None
    key, stat = after
    # With several measurement sets, whose held-out measurements (the headline's set).
    named = result.problem.formulation.headline_name
    own = "" if named is None else f" of set {named}"
    out = {
        "score": SCORES[key],
        "reference": "ground truth" if result.truth is not None else f"held-out measurements{own}",
        # With several sets, the held-out configurations the headline's set measures.
        "n_configurations": validation_protocol(result)["n_held_out"] if named is None or stat.configs is None
        else len(np.unique(stat.configs)),
        "validation_protocol": validation_protocol(result),
        "warnings": warnings(result),
        "after_m": _triple(stat),
        "before_m": _triple(before[1]) if before is not None and before[0] == key else None,
        "orientation_after_rad": None,
        "orientation_before_rad": None,
        "orientation_reference": None,
    }
    # Orientation: against the truth where it is scored there, else against the measurements.
    for scores in (result.validation, result.measured):
        name = next((k for k, v in scores.get("after", {}).items() if k.endswith("_rad") and v.errors.size), None)
        if name is None:
            continue
        out["orientation_after_rad"] = _triple(scores["after"][name])
        previous = scores.get("before", {}).get(name)
        if previous is not None and previous.errors.size:
            out["orientation_before_rad"] = _triple(previous)
        out["orientation_reference"] = "ground truth" if scores is result.validation and result.truth else (
            "held-out measurements"
        )  # fmt: skip
        break
    out["text"] = sentence(out)
    return out


def sentence(h: dict) -> str:
    def mm(t: dict) -> str:
        return f"{figure(t['rms'] * 1e3)} mm RMS, {figure(t['p95'] * 1e3)} mm P95, {figure(t['max'] * 1e3)} mm max"

    def slash(t: dict, scale: float) -> str:
        return " / ".join(figure(t[k] * scale) for k in ("rms", "p95", "max"))

    text = f"After calibration: {mm(h['after_m'])}"
    if h["before_m"] is not None:
        text += f" (before: {slash(h['before_m'], 1e3)} mm)"
    if h["orientation_after_rad"] is not None:
        scale = 180e3 / np.pi
        text += f"; orientation {figure(h['orientation_after_rad']['rms'] * scale)} mdeg RMS"
        if h["orientation_before_rad"] is not None:
            text += f" (before {figure(h['orientation_before_rad']['rms'] * scale)} mdeg)"
        if h.get("orientation_reference") != h["reference"]:
            text += f" against the {h['orientation_reference']}"
    protocol = h.get("validation_protocol")
    how = f" ({protocol['text']})" if protocol else ""
    return (
        f"{text}. {h['score'].capitalize()} on {h['n_configurations']} held-out configurations{how}, against the "
        f"{h['reference']}."
    )


def _held_out_ids(result: CalibrationResult) -> np.ndarray:
    problem = result.problem
    return np.asarray(problem.dataset.configs, dtype=object)[problem.test]


def worst_configurations(result: CalibrationResult, count: int = WORST) -> list[dict]:
    """The held-out configurations with the largest error of the main score (each scored point
    of a configuration counts; its largest is its error), largest first."""
    after = primary_score(result.validation, "after")
    if after is None or after[1].configs is None:
        return []
    stat = after[1]
    ids, problem = _held_out_ids(result), result.problem
    worst: dict[int, float] = {}
    for config, error in zip(stat.configs, stat.errors, strict=True):
        worst[int(config)] = max(worst.get(int(config), 0.0), float(error))
    ranked = sorted(worst.items(), key=lambda item: -item[1])[:count]
    return [
        {"config": str(ids[c]), "error_m": e, "joints_rad": [float(v) for v in problem.dataset.q[problem.test[c]]]}
        for c, e in ranked
        if c < len(ids)
    ]


def iso9283(result: CalibrationResult) -> dict | None:
    """Position accuracy AP and repeatability RP in the manner of ISO 9283, on the held-out
    configurations: visits of one pose (the same joint values) are grouped; AP of a pose is the
    distance from its commanded position (the model's) to the mean of the attained ones, RP is
    mean(l) + 3 s(l) of the attained positions' distances l to their mean (poses visited at least
    twice). Needs the error vectors of the main score; None without them."""
    after = primary_score(result.validation, "after")
    if after is None or after[1].vectors is None or after[1].configs is None:
        return None
    stat, problem = after[1], result.problem
    q = problem.dataset.q[problem.test]
    poses: dict[tuple, list[np.ndarray]] = {}
    seen: dict[int, int] = {}  # scored points of each configuration so far (the k-th is point k)
    for config, vector in zip(stat.configs, stat.vectors, strict=True):
        point = seen[int(config)] = seen.get(int(config), -1) + 1
        poses.setdefault((tuple(np.round(q[int(config)], 7)), point), []).append(vector)
    ap = np.array([np.linalg.norm(np.mean(v, axis=0)) for v in poses.values()])
    repeated = [np.asarray(v) for v in poses.values() if len(v) > 1]
    rp = []
    for visits in repeated:
        distances = np.linalg.norm(visits - visits.mean(axis=0), axis=1)
        rp.append(distances.mean() + 3 * distances.std(ddof=1))
    return {
        "poses": len({pose for pose, _ in poses}),
        "points": len(poses),
        "ap_mean_m": float(ap.mean()),
        "ap_max_m": float(ap.max()),
        "repeated_poses": len(repeated),
        "rp_mean_m": float(np.mean(rp)) if rp else None,
        "rp_max_m": float(np.max(rp)) if rp else None,
    }


def predicted_sigma(result: CalibrationResult) -> dict | None:
    """The predicted RMS of what the held-out score measures, and a warning when the measured
    score exceeds it by more than PREDICTION_TOLERANCE."""
    if result.prediction is None:
        return None
    predicted = result.prediction.as_dict()
    spots = result.prediction.assumes
    if spots:
        counted = f"{len(spots)} parameter{'s' if len(spots) > 1 else ''}"
        predicted["assumption"] = (
            f"the predicted held-out error assumes {counted} the fitting data "
            "cannot determine at their values, and the held-out score depends on them: their errors are not in the "
            f"prediction. What a small deviation of each moves the score by (RMS, at least): {describe(spots)}"
        )
    scored = primary_score(result.validation, "after")
    after = scored[1] if scored is not None else None
    if after is not None:
        predicted["measured_over_predicted"] = after.rms / predicted["rms"]
        if after.rms > PREDICTION_TOLERANCE * predicted["rms"]:
            predicted["warning"] = (
                f"the measured held-out error ({after.rms * 1e3:.4g} mm RMS) exceeds the predicted "
                f"({predicted['rms'] * 1e3:.4g} mm) by {after.rms / predicted['rms']:.2g}x: the model or the noise "
                "model does not describe the held-out data"
            )
    # Against the measurements (also where the headline scores the truth): a held-out error far
    # below the noise the prediction declares for it is a noise stated too large (a validation set's
    # is not fitted, so its residuals are not checked against it otherwise).
    measured_prediction = result.measured_prediction or result.prediction
    scored = primary_score(result.measured or result.validation, "after")
    if scored is not None and measured_prediction.noise_rms > NOISE_MISMATCH * scored[1].rms:
        predicted["noise_warning"] = (
            f"the measured held-out error ({scored[1].rms * 1e3:.4g} mm RMS, {scored[0]}) is "
            f"{measured_prediction.noise_rms / scored[1].rms:.3g} times smaller than the measurement noise its "
            f"prediction declares ({measured_prediction.noise_rms * 1e3:.4g} mm): check that set's noise: and the "
            "config's units"
        )
    return predicted


PREDICTION_TOLERANCE = 1.5


def _count(n: int, noun: str) -> str:
    """``1 parameter was`` or ``3 parameters were``."""
    return f"{n} {noun} was" if n == 1 else f"{n} {noun}s were"
