"""Calibration outputs: calibrated_robot.yaml, estimates.yaml, report.json, report.md with PNG
plots. Reads a finished CalibrationResult; computes nothing the calibration did not."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from ..calibration.chains import chain_sigmas
from ..calibration.covariance import correlation
from ..calibration.goodness import Fit
from ..calibration.identifiability import motion_warning
from ..calibration.prediction import workspace_map
from ..calibration.results import SCORES, CalibrationResult, primary_score, stats
from ..calibration.set_report import set_summary
from ..calibration.solve import releasable
from ..core import strict_json
from ..core.memory import release_freed_memory
from ..core.outputs import output_dir, save_figure, write_text
from ..model import kinematics
from ..model.parameters import is_motion, moment_column, split_name, unit_of
from ..model.robot import Robot
from ..model.robot_io import save_robot
from .diagnostics import motion_terms, plot_residual_diagnostics
from .estimates import write_estimates
from .headline import figure, headline, iso9283, predicted_sigma, validation_protocol, warnings, worst_configurations
from .sets import set_lines


def report_dict(result: CalibrationResult) -> dict:
    problem, config = result.problem, result.config
    formulation = problem.formulation
    robot = problem.robot
    nominal = robot.nominal_parameters()
    estimate = robot.parameter_dict(result.state.params)
    sigmas = result.sigmas
    declared = {}
    if result.covariance_declared is not None and result.released:
        declared = dict(zip(result.released, map(float, result.covariance_declared.sigmas("P")), strict=True))
    truth = result.truth.parameters if result.truth is not None else None
    absorbs: dict[str, list[str]] = {}
    for fixed, partners in result.final_identifiability.absorbed_by.items():
        for partner in partners:
            absorbs.setdefault(partner, []).append(fixed)
    deflections, angles = compliance_effects(result)
    # Joints the robot file models as elastic (bending about the parent's axes, or coupled): a
    # lightweight arm's or a humanoid's, which bend beyond what an industrial joint does.
    elastic = {*problem.robot.parent_axis, *(j for j, _ in problem.robot.compliance_coupling)}
    parameters = {}
    released_by_stages = set(releasable(problem.candidates, config.stages))
    held = result.held_from_earlier_stages
    stage_fixed = {item[1:] for stage in config.stages for item in stage if item.startswith("!")}
    for name in problem.candidates:
        entry = {
            "unit": unit_of(name),
            "nominal": nominal[name],
            "estimate": estimate[name],
            "difference_from_nominal": estimate[name] - nominal[name],
            "sigma": sigmas.get(name),
            "sigma_declared_noise": declared.get(name),
            "status": "estimated" if name in sigmas else f"held at stage {held[name]}'s estimate" if name in held
            else "fixed" if name in released_by_stages else "fixed by a stage's fix:" if name in stage_fixed
            else "not released",
        }
        if name in absorbs:
            entry["effective_value_absorbs"] = sorted(absorbs[name])
        if name in result.fixed_evidence_sigmas:  # fixed: what releasing it would show
            entry["moved_if_released_sigmas"] = result.fixed_evidence_sigmas[name]
        prior = problem.priors.sigma(name)
        if prior is not None:  # a stated prior, or fgcal's soft bound
            entry["prior_sigma"] = prior
            entry["prior"] = "stated" if problem.priors.stated(name) is not None else "soft bound"
        if name in deflections:
            entry["deflection_at_tool_max_m"] = max(deflections[name].values())
            if len(deflections[name]) > 1:  # a tree: at each tip
                entry["deflection_at_tips_max_m"] = deflections[name]
            sigma = sigmas.get(name, 0.0)
            entry["joint_deflection_max_rad"] = angles[name]
            if estimate[name] + 2.0 * sigma < 0:
                entry["flag"] = "negative compliance beyond 2 sigma: an effective correction, not a stiffness"
            elif estimate[name] < 0:
                entry["flag"] = "negative, but within 2 sigma of zero"
            elif angles[name] > PLAUSIBLE_JOINT_DEFLECTION_RAD and split_name(name)[1] - 1 not in elastic:
                entry["flag"] = (
                    f"implausible for an industrial joint: it deflects it by up to {angles[name] * 1e3:.3g} mrad "
                    f"under gravity, beyond the {PLAUSIBLE_JOINT_DEFLECTION_RAD * 1e3:g} mrad any industrial joint "
                    "bends; on an industrial arm an effective correction absorbing other errors, not a stiffness (an "
                    "elastic joint, a lightweight arm's or a humanoid's, may bend so)"
                )
        if is_motion(name) and name in sigmas and split_name(name)[0] == "lm":
            # The sign says which way (fgcal.model.motion): negative is short of the command, the
            # usual lost motion of a drive against friction; positive is an overshoot.
            side = "short of" if estimate[name] < 0 else "beyond"
            size = f"{abs(estimate[name]) * (1e3 if unit_of(name) == 'm' else 180e3 / np.pi):.3g}"
            entry["meaning"] = (
                f"lands {size} {'mm' if unit_of(name) == 'm' else 'mdeg'} {side} its command in the direction of "
                "its last move"
            )
        if truth is not None:
            entry["truth"] = float(truth[name])
        parameters[name] = entry
    validation = {}
    for label, entries in result.validation.items():
        validation[label] = {_score_name(key): value.as_dict() for key, value in entries.items()}
    intrinsics = result.state.aux.get("intrinsics")
    detection = problem.detection
    return {
        "headline": headline(result),
        "warnings": warnings(result),
        "validation_protocol": validation_protocol(result),
        "cross_validation": None if result.cross_validation is None else dict(result.cross_validation),
        # Nothing held out on a tree: each tip's fitting residuals (m), before and after.
        "fit_by_tip": None if result.fit_by_tip is None else {
            tip: {k: v for k, v in score.as_dict().items() if k != "predicted_rms_m"}
            for tip, score in result.fit_by_tip.items()
        },
        "model": config.model,
        "formulation": formulation.name,
        "formulation_source": config.formulation_source,
        "units": {"length": config.units.length, "angle": config.units.angle, "source": config.units_source},
        "robot": robot.name,
        "dataset": str(config.dataset),
        "n_configurations": len(problem.dataset.configs),
        "n_fit_configurations": len(problem.fit),
        "n_validation_configurations": len(problem.test),
        "n_residuals": int(problem.n_residuals),
        **formulation.details(problem),
        "schedule": config.schedule,
        "intrinsics": None
        if intrinsics is None
        else dict(zip(intrinsics.labels, [float(v) for v in intrinsics.value], strict=True)),
        "detection": detection.as_dict() if detection is not None else None,
        "skipped_images": [{"config": c, "reason": r} for c, r in (detection.skipped if detection else ())],
        "rejected_measurements": [r.as_dict() for r in (*problem.rejected, *result.flagged)],
        "tracker_references": result.references,
        "stages": [
            {
                "stage": s.name,
                "released": s.released,
                "residual_norm": s.residual_norm,
                **{f"residual_rms_{unit}": value for unit, value in s.residual_rms.items()},
                "iterations": s.iterations,
                "time_s": s.time_s,
                "cpu_s": s.cpu_s,
                **s.fit.as_dict(),
            }
            for s in result.stages
        ],
        "goodness_of_fit": result.fit.as_dict() if result.fit is not None else None,
        "model_comparison": [row.as_dict() for row in result.model_comparison] if result.model_comparison else None,
        "compensation": result.compensation.as_dict() if result.compensation is not None else None,
        "parameters": parameters,
        "unidentifiable": sorted(result.final_identifiability.unidentifiable),
        "unidentifiable_reasons": result.final_identifiability.unidentifiable,
        "unidentifiable_at_nominal": result.identifiability.unidentifiable,
        "motion_history_warning": motion_warning(result.final_identifiability),
        "motion_history": motion_terms(result),
        "chains": chain_sigmas(result),
        "sets": set_summary(result),
        "residual_model": result.residual_model.as_dict() if result.residual_model is not None else None,
        "identifiability": {
            "min_information": config.min_information,
            "condition_number": result.final_identifiability.condition_number,
            "singular_values": [float(v) for v in result.final_identifiability.singular_values],
        },
        "correlation": {"names": result.released, "matrix": correlation(result.parameter_covariance).tolist()},
        "strong_correlations": strong_correlations(result),
        "validation": {
            **validation,
            "scored_point_m": [float(v) for v in result.tool_point],
            "scored_point_frame": result.problem.scored_frame(result.state),
            "reference": "ground truth" if result.truth is not None else "held-out measurements",
            "gauge_removed": result.gauge,
            "predicted_position_sigma_m": predicted_sigma(result),
            "sets": validation_sets(result),
            # A tree's chains one by one: each tip's before, after and prediction (None: serial).
            "by_tip": None if result.by_tip is None else {tip: score.as_dict() for tip, score in result.by_tip.items()},
            "test_points": (
                formulation.test_point_modes(problem, result.test_observations)
                if result.test_observations is not None
                else {}
            ),
        },
        "worst_configurations": worst_configurations(result),
        "iso9283": iso9283(result),
        "estimates_file": "estimates.yaml",  # every estimate besides the robot, with sigmas (estimates.py)
        "seed": result.truth.seed if result.truth is not None else None,
        "timing": dict(result.timing),
    }


def validation_sets(result: CalibrationResult) -> list[dict] | None:
    """With separate validation sets: per set (and for the fitting dataset's own held-out
    configurations) its directory, its configurations and its part of each held-out score after
    calibration; None without them."""
    problem = result.problem
    if not problem.validation_sets:
        return None
    ids = problem.dataset.configs[problem.test]
    own = np.setdiff1d(problem.test, np.concatenate([indices for _, indices in problem.validation_sets]))
    groups = [("held out of the fitting dataset", own)] + [(path, indices) for path, indices in problem.validation_sets]
    out = []
    for name, indices in groups:
        members = set(problem.dataset.configs[indices])
        entry = {"dataset": name, "n_configurations": len(indices), "scores": {}}
        for key, stat in result.validation.get("after", {}).items():
            if stat.configs is None:
                continue
            inside = np.array([c < len(ids) and ids[c] in members for c in stat.configs], dtype=bool)
            if inside.any():
                entry["scores"][_score_name(key)] = stats(stat.errors[inside]).as_dict()
        out.append(entry)
    return out


def _score_name(key: str) -> str:
    """report.json's name of a held-out score, with its unit."""
    if key == "tool_point":
        return "position_error_m"
    for unit in ("px", "rad"):
        if key.endswith(f"_{unit}"):
            return f"{key.removesuffix(f'_{unit}')}_error_{unit}"
    return f"{key}_error_m"


GAUGE_WORDS = {
    "none": "nothing removed before scoring.",
    "translation": "a common offset removed before scoring (the data cannot fix where the robot stands: "
    "the gauge of a relative calibration).",
    "rigid": "a common rigid motion removed before scoring (the data cannot fix the robot's placement in W).",
}
STRONG_CORRELATION = 0.95
_STATS = ("mean", "rms", "p50", "p95", "max")


def strong_correlations(result: CalibrationResult) -> list[dict]:
    """Pairs of estimated parameters with |r| above STRONG_CORRELATION, strongest first."""
    r = correlation(result.parameter_covariance)
    pairs = [
        {"a": result.released[i], "b": result.released[j], "r": float(r[i, j])}
        for i in range(len(r))
        for j in range(i + 1, len(r))
        if abs(r[i, j]) > STRONG_CORRELATION
    ]
    return sorted(pairs, key=lambda p: -abs(p["r"]))


def _workspace_panel(ax, region: dict | None) -> None:
    """Top view of the held-out scored points: colour the predicted sigma, size the measured
    error (when there is one per point)."""
    if region is None:
        ax.set_visible(False)
        return
    xy = region["positions_m"][:, :2]
    sigma_mm = region["predicted_sigma_m"] * 1e3
    measured = region["measured_m"]
    sizes = 12.0 if measured is None else 8.0 + 120.0 * measured / max(float(measured.max()), 1e-12)
    points = ax.scatter(xy[:, 0], xy[:, 1], c=sigma_mm, s=sizes, cmap="viridis", edgecolors="none")
    ax.figure.colorbar(points, ax=ax, label="predicted sigma (mm)", shrink=0.85)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x in W (m)")
    ax.set_ylabel("y in W (m)")
    largest = "" if measured is None else f"\ndot size: measured error (largest {figure(measured.max() * 1e3)} mm)"
    ax.set_title(f"Held-out points, seen from above{largest}", fontsize=9)


def _region(result: CalibrationResult) -> dict | None:
    """The workspace map (fgcal.calibration.prediction.workspace_map) with, where the held-out
    score has errors at every held-out configuration, their RMS per configuration (m)."""
    problem = result.problem
    q = problem.dataset.q[problem.test]
    region = workspace_map(problem, result.state, result.covariance, q, problem.dataset.motion[problem.test])
    if region is None:
        return None
    scored = primary_score(result.validation, "after")
    region["measured_m"] = None
    if scored is not None and scored[1].configs is not None:
        errors, configs = scored[1].errors, scored[1].configs
        per_config = [errors[configs == c] for c in range(len(q))]
        if all(len(e) for e in per_config):
            region["measured_m"] = np.array([np.sqrt(np.mean(e**2)) for e in per_config])
    return region


# A gravity deflection of a joint beyond this (0.29 deg) is no stiffness: an industrial joint bends
# by a few mrad at most under its own arm and load (the seed cell's KR 125 with 125 kg: 4.7 mrad at
# most; the FARO IRB 120's DH,s,e fit gives kx2 11.3 and ky2 9.1 mrad, moving the tool 4-4.6 mm,
# effective values absorbing other errors).
PLAUSIBLE_JOINT_DEFLECTION_RAD = 0.005


def compliance_effects(result: CalibrationResult) -> tuple[dict[str, dict[str, float]], dict[str, float]]:
    """What each estimated compliance does over the fitting configurations (one kinematics pass):
    the largest displacement (m) at each tip's scored points (compliance_deflections) and the
    largest rotation (rad) of its joint (compliance_angles)."""
    problem = result.problem
    names = [n for n in result.released if unit_of(n) == "rad/(N m)"]
    if not names:
        return {}, {}
    data = kinematics.forward(problem.robot, result.state.params, problem.observations.q)
    return compliance_deflections(result, names, data), compliance_angles(result, names, data.moments)


def compliance_angles(result: CalibrationResult, names: list[str], moments: np.ndarray) -> dict[str, float]:
    """For each compliance of ``names``, the largest rotation (rad) it gives its joint over the
    configurations of ``moments`` (N, 3n): its value times the largest moment of its component."""
    index = result.problem.robot.parameter_names.index
    return {n: float(abs(result.state.params[index(n)]) * np.abs(moments[:, moment_column(n)]).max()) for n in names}


def compliance_deflections(result: CalibrationResult, names: list[str], data) -> dict[str, dict[str, float]]:
    """For each compliance of ``names``, the largest displacement (m) it causes over the
    configurations of ``data`` at each tip's scored points (a serial arm: its tool point), by tip:
    what the value means where the robot works. A tree's compliance of one arm moves that arm's tip."""
    problem = result.problem
    values = np.array([result.state.params[problem.robot.parameter_names.index(n)] for n in names])
    if isinstance(problem.frame, str):  # one frame: the report's tool point in it
        points = [(problem.scored_frame(result.state), result.tool_point)]
    else:
        scored = problem.formulation.scored(problem, result.state)
        tips = np.zeros(len(scored.points), dtype=int) if scored.tips is None else scored.tips
        points = [(problem.frame[int(t)], p) for t, p in zip(tips, scored.points, strict=True)]
    out: dict[str, dict[str, float]] = {n: {} for n in names}
    for frame, point in points:
        J = kinematics.jacobian(problem.robot, data, names, frame=frame, point=np.asarray(point))  # (N, 3, k)
        for i, name in enumerate(names):
            moved = float(np.linalg.norm(J[:, :, i] * values[i], axis=1).max())
            out[name][frame] = max(out[name].get(frame, 0.0), moved)
    return out




def write_report(result: CalibrationResult, out: str | Path, plots: bool = True) -> dict:
    """Write calibrated_robot.yaml, report.json and report.md (with PNG plots unless
    ``plots`` is false) into ``out``; returns the report as a dict."""
    out = output_dir(out)
    doc = report_dict(result)
    write_text(out / "report.json", strict_json.dumps(doc, indent=2) + "\n")
    robot, params = calibrated_robot(result)
    save_robot(
        out / "calibrated_robot.yaml",
        robot,
        params,
        notes=f"calibrated by fgcal ({doc['model']}, {doc['formulation']} formulation)",
    )
    write_estimates(result, out / "estimates.yaml")
    if plots:
        release_freed_memory()  # what the calibration freed, before the figures allocate
    figures = _plots(result, out) if plots else {}
    write_text(out / "report.md", _markdown(doc, figures))
    return doc


REGION_ROWS = 200  # fitting configurations calibrated_robot.yaml keeps as the calibrated region


def calibrated_robot(result: CalibrationResult) -> tuple[Robot, dict[str, float]]:
    """The robot and parameters calibrated_robot.yaml holds: the estimate, carrying the tool
    the calibration estimated on the flange (a probe, a ball) where it did."""
    robot = result.problem.robot
    params = robot.parameter_dict(result.state.params)
    fitted = result.problem.dataset.q[result.problem.fit]
    robot = replace(robot, region=fitted[np.unique(np.linspace(0, len(fitted) - 1, REGION_ROWS).astype(int))])
    tool = result.problem.formulation.tool_frame(result.state)
    if tool is None:
        return robot, params
    # Such a formulation never sees tool.*: it stays nominal, and the tool is the estimate.
    return robot.with_tool(tool), {k: (0.0 if k.startswith("tool.") else v) for k, v in params.items()}


def _plots(result: CalibrationResult, out: Path) -> dict[str, str]:
    # Imported here, and only the Figure class (its own Agg canvas, no pyplot state): matplotlib
    # costs a quarter of a second to import, and --no-plots skips it. Fixed margins instead of
    # tight_layout, which draws every text once more to measure it.
    from matplotlib.figure import Figure
    from matplotlib.ticker import FormatStrFormatter

    plots = {}
    before, after = (primary_score(result.validation, label) for label in ("before", "after"))
    if before is not None and after is not None:
        what = SCORES[after[0]]
        before, after = before[1], after[1]
        # One axis for both: calibration shrinks the errors by orders of magnitude, so the
        # axis is logarithmic, and the cumulative curves read off any percentile. Beside it the
        # workspace map, in the same figure (a figure of its own costs more than its artists).
        fig = Figure(figsize=(14, 4.6))
        ax, region = fig.subplots(1, 2, width_ratios=[1.7, 1])
        fig.subplots_adjust(left=0.05, right=0.98, bottom=0.12, top=0.88, wspace=0.22)
        _workspace_panel(region, _region(result))
        every = np.concatenate([before.errors, after.errors]) * 1e3
        low, high = np.log10(max(every.min(), 1e-9)), np.log10(every.max())
        bins = np.logspace(low - 0.05, high + 0.05, 60)
        cumulative = ax.twinx()
        for stat, label, colour in ((before, "before", "tab:red"), (after, "after", "tab:green")):
            errors = np.sort(stat.errors * 1e3)
            ax.hist(
                errors,
                bins=bins,
                histtype="stepfilled",
                color=colour,
                alpha=0.5,
                label=f"{label}: RMS {stat.rms * 1e3:.4g} mm",
            )  # one patch per histogram: sixty bars cost a tenth of the report
            cumulative.plot(errors, np.arange(1, len(errors) + 1) / len(errors), color=colour, lw=1.5)
        ax.set_xscale("log")
        ax.minorticks_off()  # dozens of minor ticks on a log axis cost a tenth of the report
        # Plain numbers (0.01, 0.1, 1): matplotlib's default 10^k labels start its mathtext parser.
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.set_xlabel(f"held-out {what} (mm)")
        ax.set_ylabel("count (held out)")
        cumulative.set_ylabel("fraction at most this error")
        cumulative.set_ylim(0, 1.02)
        ax.legend(loc="upper left")
        ax.set_title("Before and after calibration (bars: histogram; lines: cumulative)", y=1.0)
        save_figure(fig, out / "errors.png", dpi=100, pil_kwargs={"compress_level": 1})
        plots["errors"] = "errors.png"
    if result.released:
        corr = correlation(result.parameter_covariance)
        n = len(result.released)
        fig = Figure(figsize=(8.5, 8))
        ax = fig.subplots()
        fig.subplots_adjust(left=0.12, right=0.98, bottom=0.12, top=0.94)
        ax.imshow(corr, cmap="coolwarm", vmin=-1, vmax=1)
        # Names as plain text rather than tick labels: a matplotlib tick costs a millisecond
        # or so to build, and these were a tenth of the report's time.
        ax.set_xticks([])
        ax.set_yticks([])
        for i, name in enumerate(result.released):
            ax.text(i, n - 0.4, name, rotation=90, fontsize=7, ha="center", va="top")
            ax.text(-0.7, i, name, fontsize=7, ha="right", va="center")
        ax.set_title("Correlation of the estimated parameters (blue -1, grey 0, red +1)", y=1.0)
        save_figure(fig, out / "correlation.png", dpi=100, pil_kwargs={"compress_level": 1})
        plots["correlation"] = "correlation.png"
    diagnostics = plot_residual_diagnostics(result, out)
    if diagnostics is not None:
        plots["residual_diagnostics"] = diagnostics
    return plots


def _released_text(released: list[str]) -> str:
    return f"{len(released)}: {', '.join(released)}" if released else "none (the auxiliary unknowns alone)"


def _motion_lines(motion: dict | None, diagnostics: str | None) -> list[str]:
    """The motion history's terms per joint (mdeg, or um for a prismatic joint) and the
    residual diagnostics."""
    lines = []
    if motion is not None:
        terms = motion["per_joint"]
        lines += [
            "", "## Motion history (lost motion and the speed term)", "",
            "Each joint's offset by how it was reached (docs/model.md, Motion history): lost motion `lm` (half the "
            "dead band at a reversal) and the speed term `lv` (at the program's speed). Estimate +- sigma; "
            "fixed: not identifiable from this data.", "",
            "| joint | lost motion lm | speed term lv |", "|---|---|---|",
        ]  # fmt: skip
        for j, prismatic in enumerate(motion["prismatic"]):
            scale, unit = (1e6, "um") if prismatic else (np.degrees(1.0) * 1e3, "mdeg")
            cells = []
            for key in ("lost_motion", "speed"):
                value, sigma = terms[key][j], terms[f"{key}_sigma"][j]
                cells.append(
                    f"{value * scale:.3g} {unit} (fixed)" if sigma is None
                    else f"{value * scale:.3g} +- {sigma * scale:.2g} {unit}"
                )  # fmt: skip
            lines.append(f"| {j + 1} | {cells[0]} | {cells[1]} |")
    if diagnostics is not None:
        lines += [
            "", "## What is left", "",
            "The held-out error of each configuration against each joint's last move, the order of measurement and "
            "each joint's angle: a trend in one of them is what the model has not explained.", "",
            f"![residual diagnostics]({diagnostics})",
        ]  # fmt: skip
    return lines


def _chain_lines(chains: dict | None) -> list[str]:
    """The shared parameters' sigmas from each tip's measurements alone and from all of them."""
    if chains is None:
        return []
    tips = chains["tips"]
    if not chains["parameters"]:
        return [
            "", "## Shared by the chains", "",
            f"No estimated parameter moves more than one tip's measurements ({', '.join(tips)}): each chain is "
            "determined by its own (what they share, such as the base, is fixed by the instrument's frame).",
        ]  # fmt: skip
    lines = [
        "", "## Shared by the chains", "",
        "Parameters that move more than one tip's measurements (a shared torso, where a positioner stands): their "
        "sigma from each tip's measurements alone and from all of them, at the estimate under the declared noise "
        "(mm, mdeg, urad/(N m), mass scales as factors); -: not identifiable from that tip alone.", "",
        "| parameter | " + " | ".join(f"{tip} alone" for tip in tips) + " | all |",
        "|---|" + "---|" * (len(tips) + 1),
    ]  # fmt: skip
    for name, entry in chains["parameters"].items():
        _, fmt = _units(unit_of(name))
        cells = [fmt(entry["sigma_by_tip"][tip]) for tip in tips] + [fmt(entry["sigma_all"])]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def _residual_model_lines(model: dict | None) -> list[str]:
    if model is None:
        return []
    verdict = (
        "It wins on the fitting data: its held-out figures are below." if model["used"]
        else "It does not win on the fitting data: it is not used."
    )  # fmt: skip
    lines = [
        "", "## Residual model (Gaussian process)", "",
        "What the kinematic model leaves, learned from the fitting configurations as a function of the joints and "
        "how each was reached (docs/calibration.md, Residual model). Cross-validated on the fitting data "
        f"({model['folds']} folds, seed {model['seed']}): {model['cv_rms_with_m'] * 1e3:.4g} mm RMS with it, "
        f"{model['cv_rms_without_m'] * 1e3:.4g} mm without. {verdict}",
    ]  # fmt: skip
    if model["held_out_rms_m"] is not None:
        lines += [
            "",
            f"Held out, against the held-out measurements (not a simulation's truth): "
            f"{model['held_out_rms_m'] * 1e3:.4g} mm RMS with it (predicted "
            f"{model['predicted_rms_m'] * 1e3:.4g} mm), {model['held_out_rms_without_m'] * 1e3:.4g} mm without.",
        ]
    lines += [
        "", f"Kernel: `{model['kernel']}` (lengths in rad and the motion features' units). The headline figures, "
        "calibrated_robot.yaml and fgcal compensate are the kinematic model's: the correction is not exported.",
    ]  # fmt: skip
    return lines


def fit_sentence(fit: dict) -> str:
    return Fit(fit["chi2"], fit["dof"], fit["chi2_p_value"]).sentence()


def _units(unit: str):
    """(format of a value, format of a difference or sigma) for an SI unit, in the units an
    engineer reads: mm; deg and mdeg; urad/(N m)."""

    def fmt(scale: float, spec: str):
        return lambda v: "-" if v is None else format(v * scale, spec)

    if unit == "m":
        return fmt(1e3, ".4f"), fmt(1e3, ".4g")
    if unit == "rad":
        return fmt(180.0 / np.pi, ".5f"), fmt(180e3 / np.pi, ".4g")
    if unit == "1":  # a mass scale
        return fmt(1.0, ".4f"), fmt(1.0, ".3g")
    return fmt(1e6, ".4g"), fmt(1e6, ".4g")


def _references_lines(check: dict) -> list[str]:
    """The tracker's stability section (fgcal.calibration.references), in mm."""
    lines = [
        "",
        "## Tracker stability (reference reflectors)",
        "",
        f"The references moved by {check['common_drift_norm_m'] * 1e3:.4g} mm in common over the session "
        "(the tracker's own drift, which the calibration cannot tell from the robot's errors). "
        f"Method: {check['method']}.",
        "",
        "| reference | readings | noise sigma (mm) | drift (mm) | misreads | largest misread (mm) |",
        "|---|---|---|---|---|---|",
    ]
    for name, t in check["targets"].items():
        if "note" in t:
            lines.append(f"| {name} | {t['readings']} | - | - | {t['note']} | - |")
            continue
        largest = "-" if t["largest_misread_m"] is None else f"{t['largest_misread_m'] * 1e3:.4g}"
        shown = ", ".join(t["misreads"][:8]) + (", ..." if len(t["misreads"]) > 8 else "")
        lines.append(
            f"| {name} | {t['readings']} | {t['noise_sigma_m'] * 1e3:.3g} | {t['drift_norm_m'] * 1e3:.3g} | "
            f"{len(t['misreads'])}{f' ({shown})' if shown else ''} | {largest} |"
        )
    return lines


def _iso_lines(iso: dict | None) -> list[str]:
    if not iso:
        return []
    lines = [
        "",
        f"In the manner of ISO 9283, over {iso['poses']} held-out poses ({iso['points']} scored points): position "
        "accuracy AP (the distance from "
        f"where the model commands to the mean of where the robot went) {figure(iso['ap_mean_m'] * 1e3)} mm on "
        f"average, {figure(iso['ap_max_m'] * 1e3)} mm at worst; ",
    ]
    if iso["repeated_poses"]:
        lines[-1] += (
            f"repeatability RP (mean distance to that mean plus three standard deviations) over "
            f"{iso['repeated_poses']} poses visited more than once: {figure(iso['rp_mean_m'] * 1e3)} mm on average, "
            f"{figure(iso['rp_max_m'] * 1e3)} mm at worst."
        )
    else:
        lines[-1] += "repeatability RP: no pose was visited twice."
    return lines


def _worst_lines(worst: list[dict] | None) -> list[str]:
    if not worst:
        return []
    lines = [
        "",
        f"The {len(worst)} worst held-out configurations:",
        "",
        "| configuration | error (mm) | joints (deg) |",
    ]
    lines.append("|---|---|---|")
    for row in worst:
        joints = ", ".join(f"{np.degrees(v):.1f}" for v in row["joints_rad"])
        lines.append(f"| {row['config']} | {figure(row['error_m'] * 1e3)} | {joints} |")
    return lines


def _markdown(doc: dict, plots: dict[str, str]) -> str:
    lines = [f"# Calibration report: {doc['robot']}", ""]
    if doc["headline"] is not None:
        lines += [f"**{doc['headline']['text']}**", ""]
    lines += [f"**Warning:** {warning}.\n" for warning in doc["warnings"]]
    if doc["headline"] is None:
        lines += [f"Held out: {doc['validation_protocol']['text']}.", ""]
    lines += [
        f"Model **{doc['model']}**, **{doc['formulation']}** formulation"
        + ("" if doc["formulation_source"] == "the config" else f" ({doc['formulation_source']})")
        + f", schedule {doc['schedule']}. The config's lengths in {doc['units']['length']}, angles in "
        f"{doc['units']['angle']} ({doc['units']['source']}). "
        + (f"{doc['n_fit_configurations']} configurations for fitting, all of them (the fit the "
           f"{doc['cross_validation']['folds']} folds of the headline score), "
           if doc.get("cross_validation") else
           f"{doc['n_fit_configurations']} configurations for fitting, {doc['n_validation_configurations']} held out, ")
        + f"{doc['n_residuals']} residuals. Total time {doc['timing']['total_s']:.2f} s."
        + (f" Simulation seed {doc['seed']}." if doc["seed"] is not None else ""),
        "",
    ]
    val = doc["validation"]
    if val.get("after"):
        lines += [
            "## Held-out error",
            "",
            (
                "Reference: the point pairs of the held-out images, grouped as the fitting ones (a pair "
                "does not depend on where the robot stands: no gauge)."
                if "point_pair_error_m" in val["after"]
                else "Reference: the held-out images' pixels, reprojected with the estimated robot, fixture pose "
                "and intrinsics; each pixel error times the point's depth over the focal length (m)."
                if "reprojection_error_m" in val["after"]
                else f"Reference: {val['reference']}; {GAUGE_WORDS[val['gauge_removed']]}"
                + (
                    f" Scored: set {doc['sets']['headline_set']}'s held-out measurements, at its own points."
                    if doc.get("sets") and val["reference"] != "ground truth"
                    else f" Scored point in the {val['scored_point_frame']} frame: "
                    f"({', '.join(f'{v * 1e3:.3f}' for v in val['scored_point_m'])}) mm."
                    if val["scored_point_m"]
                    else ""
                )
            ),
            "",
            "| | mean | RMS | P50 | P95 | max | RMS x, y, z |",
            "|---|---|---|---|---|---|---|",
        ]
        for label in ("before", "after"):
            for key, stat in val[label].items():
                scale, unit = (
                    (1.0, "px")
                    if key.endswith("_px")
                    else (180.0 / np.pi, "deg")
                    if key.endswith("_rad")
                    else (1e3, "mm")
                )
                cells = " | ".join("-" if stat[k] is None else figure(stat[k] * scale) for k in _STATS)
                axes = ", ".join(figure(stat["rms_" + a] * scale) for a in "xyz") if "rms_x" in stat else "-"
                name = key.removesuffix("_m").removesuffix("_px").removesuffix("_rad").replace("_", " ")
                lines.append(f"| {label}: {name} ({unit}) | {cells} | {axes} |")
        if val.get("predicted_position_sigma_m"):
            p = val["predicted_position_sigma_m"]
            noise = f" and the measurement noise ({p['noise_rms'] * 1e3:.4g} mm)" if p["noise_rms"] else ""
            lines += [
                "",
                f"Predicted held-out error: {p['rms'] * 1e3:.4g} mm RMS, from the estimate's uncertainty "
                f"({p['parameters_rms'] * 1e3:.4g} mm){noise}, with the score's gauge removed"
                + (
                    f"; measured / predicted = {p['measured_over_predicted']:.3g}."
                    if "measured_over_predicted" in p
                    else "."
                ),
            ]
            if "warning" in p:  # (the headline's warnings say it first)
                lines += ["", "Measured above the prediction: see the warnings at the top."]
            if p.get("assumes_at_their_values"):
                names = ", ".join(spot["name"] for spot in p["assumes_at_their_values"])
                lines += ["", f"The prediction holds only with {names} at their values: the fitting data cannot "
                          "determine them and the held-out score depends on them (see the warnings at the top)."]
        if val.get("by_tip"):
            lines += ["", "Held out per tip (each chain on its own; RMS, mm):", "",
                      "| tip | errors | before | after | predicted |", "|---|---|---|---|---|"]  # fmt: skip
            for tip, entry in val["by_tip"].items():
                cells = [figure(entry[k] * 1e3) if entry[k] is not None else "-"
                         for k in ("before_rms_m", "after_rms_m", "predicted_rms_m")]  # fmt: skip
                lines.append(f"| {tip} | {entry['n_errors']} | " + " | ".join(cells) + " |")
        if val.get("sets"):
            lines += ["", "Held-out sets after calibration (RMS, mm):", ""]
            for entry in val["sets"]:
                scores = ", ".join(
                    f"{name.replace('_', ' ')} {stat['rms'] * 1e3:.4g}" for name, stat in entry["scores"].items()
                    if name.endswith("_m")
                )  # fmt: skip
                lines.append(f"- {entry['dataset']} ({entry['n_configurations']} configurations): {scores or '-'}")
        if val.get("test_points"):
            modes = ", ".join(f"{name} ({mode})" for name, mode in val["test_points"].items())
            lines += ["", f"Test points, measured only at held-out configurations: {modes}."]
        if "errors" in plots:
            lines += ["", f"![errors]({plots['errors']})"]
        lines += _iso_lines(doc.get("iso9283")) + _worst_lines(doc.get("worst_configurations"))
    if doc.get("fit_by_tip"):
        lines += ["", "## Fitting residuals per tip", "", "Nothing is held out: each chain's residuals on the fitting "
                  "measurements (RMS, mm), which say how each tip fits, not how it holds out.", "",
                  "| tip | residuals | before | after |", "|---|---|---|---|"]  # fmt: skip
        for tip, entry in doc["fit_by_tip"].items():
            lines.append(f"| {tip} | {entry['n_errors']} | {figure(entry['before_rms_m'] * 1e3)} | "
                         f"{figure(entry['after_rms_m'] * 1e3)} |")  # fmt: skip
        lines.append("")
    if doc["rejected_measurements"]:
        lines += ["", f"## Rejected measurements ({len(doc['rejected_measurements'])})", ""]
        lines += ["| config | kind | point or target | size (sigmas) | size |", "|---|---|---|---|---|"]
        for r in doc["rejected_measurements"]:
            size = f"{r['size_m'] * 1e3:.4g} mm" if "size_m" in r else f"{r['size_px']:.4g} px"
            lines.append(
                f"| {r['config']} | {r['kind']} | {r.get('point', r.get('target'))} | {r['size_sigma']:.3g} | {size} |"
            )
    if doc.get("tracker_references"):
        lines += _references_lines(doc["tracker_references"])
    if doc.get("compensation"):
        c = doc["compensation"]
        lines += [
            "",
            "## Compensation (simulated)",
            "",
            f"{c['n_targets']} random targets in the calibrated region, each from a hint 0.05 rad off, driven "
            f"through the simulated true robot ({c['gauge_removed']} gauge removed, as in the held-out score; "
            f"statuses: {', '.join(f'{k} {v}' for k, v in c['status'].items())}):",
            "",
            "| joints from | RMS error at the target (mm) |",
            "|---|---|",
            f"| the controller's nominal model (uncompensated) | {c['uncompensated_rms_m'] * 1e3:.4g} |",
            f"| the calibrated model (compensated) | {c['compensated_rms_m'] * 1e3:.4g} |",
        ]
        if c.get("without_approach_rms_m") is not None:
            lines.append(
                f"| the calibrated model, lost motion not allowed for | {c['without_approach_rms_m'] * 1e3:.4g} |"
            )
        residual_m = c["model_residual_max_m"]
        reached = "within 1 nm" if residual_m < 1e-9 else f"to {residual_m * 1e6:.2g} um"
        lines += [
            "",
            f"Compensation removes {c['improvement']:.0f}x of the error; in the calibrated model every scored "
            f"target is reached {reached}.",
        ]
    fit = doc["goodness_of_fit"]
    if fit is not None:
        lines += ["", "## Goodness of fit", "", fit_sentence(fit)]
    if doc["model_comparison"]:
        supported = next(row["model"] for row in doc["model_comparison"] if row["supported"])
        lines += [
            "",
            "## Model choice",
            "",
            f"The same data fitted with each model (information criteria with the noise level estimated from the "
            f"data). The data support **{supported}** (lowest BIC); this report is of that fit.",
            "",
            "| model | unknowns | chi2/dof | held-out RMS (mm) | AIC | BIC | time (s) |",
            "|---|---|---|---|---|---|---|",
        ]
        for row in doc["model_comparison"]:
            held = "-" if row["held_out_rms_m"] is None else f"{row['held_out_rms_m'] * 1e3:.4g}"
            lines.append(
                f"| {row['model']}{' (supported)' if row['supported'] else ''} | {row['n_unknowns']} | "
                f"{row['chi2_per_dof']:.3g} | {held} | {row['aic']:.1f} | {row['bic']:.1f} | {row['time_s']:.2f} |"
            )
    lines += [
        "",
        "## Stages",
        "",
        "| stage | released | residual RMS | chi2 / dof | p | iterations | time (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in doc["stages"]:
        rms_text = ", ".join(
            f"{s[key] * scale:.4g} {unit}"
            for key, scale, unit in (("residual_rms_m", 1e3, "mm"), ("residual_rms_rad", 1e3, "mrad"),
                                     ("residual_rms_px", 1.0, "px"))
            if key in s
        )  # fmt: skip
        lines.append(
            f"| {s['stage']} | {_released_text(s['released'])} | {rms_text} | "
            f"{s['chi2']:.4g} / {s['dof']} = {s['chi2_per_dof']:.3g} | {s['chi2_p_value']:.2g} | "
            f"{s['iterations']} | {s['time_s']:.2f} |"
        )
    has_truth = any("truth" in p for p in doc["parameters"].values())
    lines += [
        "",
        "## Parameters",
        "",
        "Lengths in mm, angles in deg (differences and sigmas in mdeg), compliances in urad/(N m), mass scales as "
        "factors; "
        "report.json has every value in SI.",
        "",
        "| name | nominal | estimate | estimate - nominal | sigma | "
        + ("truth - estimate | " if has_truth else "")
        + "status |",
        "|---|---|---|---|---|" + ("---|" if has_truth else "") + "---|",
    ]
    for name, p in doc["parameters"].items():
        big, small = _units(p["unit"])
        status = p["status"]
        if "effective_value_absorbs" in p:
            status += f"; effective value (absorbs {', '.join(p['effective_value_absorbs'])})"
        if "deflection_at_tips_max_m" in p:  # a tree: at each tip
            tips = ", ".join(f"{tip} {moved * 1e3:.3g} mm" for tip, moved in p["deflection_at_tips_max_m"].items())
            status += f"; moves the tips up to: {tips}"
        elif "deflection_at_tool_max_m" in p:
            status += f"; moves the tool up to {p['deflection_at_tool_max_m'] * 1e3:.3g} mm"
        if "flag" in p:
            status += f"; **{p['flag']}**"
        if "meaning" in p:
            status += f"; {p['meaning']}"
        if p.get("prior") == "stated":
            status += f"; prior sigma {small(p['prior_sigma'])}"
        if p.get("moved_if_released_sigmas", 0.0) > 10:
            status += f"; **a fit releasing it moves it by {p['moved_if_released_sigmas']:.3g} sigma**"
        lines.append(
            f"| {name} | {big(p['nominal'])} | {big(p['estimate'])} | {small(p['difference_from_nominal'])} | "
            f"{small(p['sigma'])} | " + (f"{small(p['truth'] - p['estimate'])} | " if has_truth else "") + f"{status} |"
        )
    if doc["strong_correlations"]:
        lines += ["", f"Strongly correlated estimates (|r| > {STRONG_CORRELATION}):", ""]
        lines += [f"- {c['a']} and {c['b']}: r = {c['r']:+.3f}" for c in doc["strong_correlations"]]
    lines += ["", "## Unidentifiable parameters (fixed at their current values)", ""]
    if doc["motion_history_warning"]:
        lines += [f"**Warning:** {doc['motion_history_warning']}.", ""]
    for name, reason in doc["unidentifiable_reasons"].items():
        lines.append(f"- `{name}`: {reason}")
    ident = doc["identifiability"]
    lines += [
        "",
        f"Condition number of the identifiable set (scaled, whitened Jacobian): "
        f"{ident['condition_number']:.4g}; threshold min_information = {ident['min_information']}. "
        "Singular values, largest first: " + ", ".join(f"{v:.3g}" for v in ident["singular_values"]) + ".",
    ]
    if "correlation" in plots:
        lines += ["", "## Correlations", "", f"![correlation]({plots['correlation']})"]
    lines += _motion_lines(doc["motion_history"], plots.get("residual_diagnostics"))
    lines += _residual_model_lines(doc["residual_model"])
    lines += _chain_lines(doc["chains"])
    against_truth = (doc.get("validation") or {}).get("reference") == "ground truth"
    lines += set_lines(doc.get("sets"), lambda unit: _units(unit)[1], against_truth)
    return "\n".join(lines) + "\n"
