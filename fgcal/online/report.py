"""The online report: ``report.md`` and ``sigmas.png`` (sigma / prior sigma image by image)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..core.outputs import save_figure, write_text
from ..model.parameters import unit_of


def read_history(state: Path) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """(released names, image numbers, predicted RMS accuracy (m), sigmas (images x names))."""
    with open(state / "history.csv", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    names = [h.removeprefix("sigma_") for h in header if h.startswith("sigma_")]
    first = header.index(f"sigma_{names[0]}") if names else len(header)
    images = np.array([int(r[0]) for r in body])
    predicted = np.array([float(r[header.index("predicted_rms_m")]) for r in body])
    sigmas = np.array([[float(v) for v in r[first:]] for r in body]).reshape(len(body), len(names))
    return names, images, predicted, sigmas


def plot_sigmas(state: Path, report: dict) -> Path | None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, images, predicted, sigmas = read_history(state)
    if not len(images):
        return None
    prior = np.array([report["parameters"][n]["prior_sigma"] for n in names])
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 8), sharex=True)
    for i, name in enumerate(names):
        top.semilogy(images, sigmas[:, i] / prior[i], lw=0.8, label=name)
    top.set_ylabel("sigma / prior sigma")
    top.set_title(f"{report['robot']}: marginal sigmas image by image")
    top.legend(ncol=4, fontsize=6, loc="lower left")
    bottom.semilogy(images, predicted * 1e3, color="k", label="predicted RMS flange position sigma")
    bottom.axhline(report["stopping_rule"]["target_m"] * 1e3, color="tab:green", ls="--", label="target")
    for alarm in report["alarms"]:
        bottom.axvline(alarm["image"], color="tab:red", lw=0.8)
    bottom.set_xlabel("image")
    bottom.set_ylabel("mm")
    bottom.legend(fontsize=8)
    fig.tight_layout()
    path = state / "sigmas.png"
    save_figure(fig, path, dpi=110)
    plt.close(fig)
    return path


def write_final_report(state: Path, report: dict) -> None:
    plot = plot_sigmas(state, report)
    rule = report["stopping_rule"]
    accuracy = report["predicted_accuracy"]
    lines = [f"# Online calibration of {report['robot']}", ""]
    steps = [p for p in report["problems"] if "in one measurement: the estimate is not to be trusted" in p]
    if report.get("implausible") or steps:
        moved = report.get("implausible") or []
        why = [f"moved more than 10 prior sigmas from the start: {', '.join(moved)}"] if moved else []
        if steps:
            why.append(f"{len(steps)} step(s) beyond 1000 sigmas in one measurement, the first {steps[0]}")
        lines += [
            "**Warning: this estimate is not to be trusted** ("
            + "; ".join(why)
            + "): check the measurements and the gate (outlier_gate_sigma) before using calibrated_robot.yaml.",
            "",
        ]
    lines += [
        f"- measurements folded in: {report['n_images']} (logged {report['n_logged']}, "
        f"skipped {len(report['skipped'])})",
        f"- predicted flange position sigma over the window: RMS {accuracy['rms_m'] * 1e3:#.4g} mm, "
        f"max {accuracy['max_m'] * 1e3:#.4g} mm ({accuracy['n_configurations']} configurations)",
        f"- stopping rule ({rule['rule']}, target {rule['target_m'] * 1e3:#.3g} mm): "
        + (f"met at measurement {rule['met_at_image']}" if rule["met"] else "not met yet"),
        f"- drift alarms (measurements that raised one): {len(report['alarms'])} (test: false-alarm rate "
        f"{report['alarm_test']['false_alarm_rate_per_image']:g} per measurement, |z| > "
        f"{report['alarm_test']['threshold_z']:.2f}, lag {report['alarm_test']['lag_images']} measurements)",
    ]
    if report["latency_ms"]["n_updates"]:
        latency = report["latency_ms"]
        lines.append(
            f"- update latency over {latency['n_updates']} updates: median {latency['median']:.1f} ms, "
            f"p99 {latency['p99']:.1f} ms"
        )
    if report["prior_dominated"]:
        lines.append(f"- still dominated by their priors (sigma > prior/2): {', '.join(report['prior_dominated'])}")
    for problem in report["problems"]:
        lines.append(f"- problem: {problem}")
    lines += [
        "",
        "Lengths in mm, angles in deg (changes and sigmas in mdeg), compliances in urad/(N m); report.json "
        "holds the same in SI.",
        "",
        "| parameter | estimate | change from the start | sigma | sigma / prior |",
        "|---|---|---|---|---|",
    ]
    for name, entry in report["parameters"].items():
        if entry["status"] == "released":
            scale, label = human_unit(entry["unit"])
            value = (
                f"{np.degrees(entry['estimate']):.5f} deg"
                if entry["unit"] == "rad"
                else f"{entry['estimate'] * scale:.4f} {label}".rstrip()
            )
            lines.append(
                f"| {name} | {value} | {human(name, entry['estimate'] - entry['start'])} | "
                f"{entry['sigma'] * scale:.3g} {label} | {entry['sigma'] / entry['prior_sigma']:.3g} |"
            )
    if report["alarms"]:
        lines += ["", "## Drift alarms", "", "| image | file | parameters (z, change) |", "|---|---|---|"]
        for alarm in report["alarms"]:
            shown = alarm["parameters"][:6]
            flagged = "; ".join(
                f"{p['parameter']} ({p['z']:+.1f}, {human(p['parameter'], p['change'])})" for p in shown
            )
            more = len(alarm["parameters"]) - len(shown)
            lines.append(f"| {alarm['image']} | {alarm['name']} | {flagged}{f'; {more} more' if more else ''} |")
    if plot is not None:
        lines += ["", f"![sigmas]({plot.name})"]
    write_text(state / "report.md", "\n".join(lines) + "\n")


def human_unit(unit: str) -> tuple[float, str]:
    """(scale, label) of a change or a sigma in the units an engineer reads, as the batch
    report: mm, mdeg, urad/(N m)."""
    return {"m": (1e3, "mm"), "rad": (180e3 / np.pi, "mdeg"), "rad/(N m)": (1e6, "urad/(N m)")}.get(unit, (1.0, unit))


def human(name: str, change: float) -> str:
    """A change of parameter ``name`` (SI) in mm, mdeg or urad/(N m), with its sign."""
    scale, label = human_unit(unit_of(name))
    return f"{change * scale:+.4g} {label}".rstrip()
