"""report.md's section on a calibration with several measurement sets (a config's ``sets:``):
per set its rows, residual RMS in its own unit, chi2/dof and held-out score, and each parameter's
sigma from each fitting set alone and from all (fgcal.calibration.set_report)."""

from __future__ import annotations

from ..model.parameters import unit_of
from .headline import figure

_SHOWN = {"m": (1e3, "mm"), "rad": (1e3, "mrad"), "px": (1.0, "px")}


def _value(value: float | None, unit: str) -> str:
    if value is None:
        return "-"
    scale, shown = _SHOWN.get(unit, (1e3, "mm"))
    return f"{figure(value * scale)} {shown}"


def set_lines(sets: dict | None, sigma_units, against_truth: bool = False) -> list[str]:
    """The "Measurement sets" section of report.md (empty without sets); ``sigma_units(name)`` is
    the format of a parameter's sigma (the report's); ``against_truth``: the headline scores
    against a simulation's truth, not against a set's measurements."""
    if sets is None:
        return []
    headline = (
        "The headline scores against the simulation's ground truth; against measurements, the held-out score "
        f"reported first is set {sets['headline_set']}'s" if against_truth
        else f"The headline's held-out score is set {sets['headline_set']}'s"
    )  # fmt: skip
    lines = [
        "", "## Measurement sets", "",
        f"{headline} (the first validation set, else the first "
        "fitting set). Per set: its rows, its residual RMS at the estimate in its own unit, its chi2 over its "
        "degrees of freedom (its rows less its share of the unknowns: about 1 when its declared noise is right), and "
        "its held-out score after calibration with its prediction. A validation set is never fitted: its own "
        "unknowns are registered with the robot held at the calibration, on its fitting configurations (on all of them "
        "when nothing of it is held out, and scored there).", "",
        "| set | formulation | use | rows | residual RMS | chi2/dof | held out before | after | predicted |",
        "|---|---|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for entry in sets["sets"]:
        residual = ", ".join(_value(v, k.removeprefix("residual_rms_")) for k, v in entry.items()
                             if k.startswith("residual_rms_")) or "-"  # fmt: skip
        chi2 = entry.get("chi2_per_dof")
        after = entry["held_out"]["after"]
        main = next(iter(after), None)
        unit = main.rsplit("_", 1)[-1] if main else "m"
        before = entry["held_out"]["before"].get(main) if main else None
        on = entry.get("registered_on")
        use = entry["use"] + (
            " (nothing held out: registered and scored on all its configurations)" if on == "all"
            else f" (registered on {on})" if on else ""
        )  # fmt: skip
        lines.append(
            f"| {entry['name']} | {entry['formulation']} | {use} | {entry.get('n_rows', '-')} | {residual} | "
            f"{'-' if chi2 is None else f'{chi2:.3g}'} | {_value(before, unit)} | "
            f"{_value(after.get(main) if main else None, unit)} | {_value(entry['predicted_rms_m'], 'm')} |"
        )
    fitting = [e["name"] for e in sets["sets"] if e["use"] == "fit"]
    if sets["parameters"] and len(fitting) > 1:
        lines += [
            "", "Each released parameter's sigma from each fitting set alone (its own unknowns estimated alongside) "
            "and from all of them, at the estimate under the declared noise (mm, mdeg, urad/(N m), mass scales as "
            "factors); -: not identifiable from that set alone. A set alone holds the parameters it cannot determine "
            "at the estimate, so its sigmas of the others are conditional on them: where all sets together estimate "
            "such a parameter, a sigma from all can exceed one from a set alone.", "",
            "| parameter | " + " | ".join(f"{name} alone" for name in fitting) + " | all |",
            "|---|" + "---|" * (len(fitting) + 1),
        ]  # fmt: skip
        for name, entry in sets["parameters"].items():
            fmt = sigma_units(unit_of(name))
            cells = [fmt(entry["sigma_by_set"][s]) for s in fitting] + [fmt(entry["sigma_all"])]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines
