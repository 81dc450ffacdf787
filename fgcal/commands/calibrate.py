"""``fgcal calibrate CONFIG``: a calibration as its config describes, and its report."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ..core.console import Reporter, detail, say, warn
from .options import JSON_HELP, emit


def score(result):
    """After the calibration: a simulated dataset is scored against its truth (truth/)."""
    from ..calibration.run import held_out_summary
    from ..calibration.scoring import score_with_truth

    result = score_with_truth(result)
    line = held_out_summary(result)
    if line:
        say(line)
    return result


REPORT_FILES = ("report.md", "report.json", "calibrated_robot.yaml", "estimates.yaml")


def _inputs(config) -> dict[str, Path]:
    """Every file a calibration reads: its config, the dataset's and validation sets' files (and
    their truth), and the robot file a dataset header names."""
    import yaml

    inputs = {"CONFIG": Path(config.path)}
    for folder in [Path(config.dataset), *map(Path, config.validation_datasets)]:
        try:
            robot = yaml.safe_load((folder / "dataset.yaml").read_text(encoding="utf-8")).get("robot")
        except (OSError, ValueError, AttributeError, yaml.YAMLError):  # loading the dataset says what is wrong
            robot = None
        if isinstance(robot, str) and (folder / robot).is_file():
            inputs[f"the robot file of the dataset {folder}"] = folder / robot
        for path in [*folder.glob("*"), *(folder / "truth").glob("*")]:
            if path.is_file():
                inputs[f"the dataset's file {path}"] = path
    return inputs


def cmd_calibrate(args: argparse.Namespace) -> int:
    from ..calibration.config import load_config
    from ..calibration.run import calibrate
    from ..core.outputs import distinct
    from ..reports.calibration import write_report

    config = load_config(args.config)
    # Before the work: a report written over the robot file, the config or a table it reads
    # (--out the dataset's own folder, with its robot: calibrated_robot.yaml) would destroy it.
    distinct({f"--out ({name})": Path(args.out) / name for name in REPORT_FILES}, _inputs(config))

    if config.folds is not None and config.fold is None:  # every fold, then the fit on all
        from ..calibration.cross_validation import cross_validate

        result = cross_validate(config, lambda one: score(calibrate(one, progress=Reporter())), say)
        cv = result.cross_validation
        predicted = f" (predicted {cv['pooled_predicted_rms_m'] * 1e3:.4g} mm)" if cv["pooled_predicted_rms_m"] else ""
        say(f"  {cv['folds']}-fold cross-validation, {cv['n_held_out']} configurations held out in all: "
            f"{cv['pooled_after_rms_m'] * 1e3:.4g} mm RMS pooled{predicted}")  # fmt: skip
    else:
        result = score(calibrate(config, progress=Reporter()))
    started = time.perf_counter()
    doc = write_report(result, args.out, plots=not args.no_plots)
    say(
        f"wrote {args.out}/report.md, report.json, calibrated_robot.yaml, estimates.yaml "
        f"(calibration {result.timing['total_s']:.2f} s, report {time.perf_counter() - started:.2f} s)"
    )
    for name, entry in doc["parameters"].items():  # with -v: every estimate, in the units of report.md
        if entry.get("sigma") is not None:
            scale, unit = {"m": (1e3, "mm"), "rad": (180e3 / np.pi, "mdeg")}.get(entry["unit"], (1.0, entry["unit"]))
            detail(
                f"  {name:10s} {entry['difference_from_nominal'] * scale:+#.4g} {unit} from nominal, "
                f"sigma {entry['sigma'] * scale:#.3g} {unit}"
            )
    for warning in doc["warnings"]:  # the report's headline warnings, on the console too
        warn(warning)
    out = Path(args.out)
    files = list(REPORT_FILES)
    emit(args, {
        "out": str(out), "files": {name: str(out / name) for name in files},
        "model": doc["model"], "formulation": doc["formulation"], "headline": doc["headline"],
        "goodness_of_fit": doc["goodness_of_fit"], "seed": doc["seed"], "warnings": doc["warnings"],
        "validation_protocol": doc["validation_protocol"],
    })  # fmt: skip
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="calibrate from a dataset as a calibration config describes")
    p.add_argument("config", help="calibration config YAML (docs/calibration.md)")
    p.add_argument("--out", required=True, help="output directory for the report and calibrated robot")
    p.add_argument("--no-plots", action="store_true", help="write report.md without the PNG plots")
    p.add_argument("--json", action="store_true", help=JSON_HELP)
    p.set_defaults(func=cmd_calibrate)
