"""``fgcal simulate``: a cell's true robot, configurations and measurements, with ground truth."""

from __future__ import annotations

import argparse

import numpy as np

from ..core.console import Reporter, say
from ..simulation import MAX_CONFIGURATIONS
from .options import CONFIGURATIONS, JSON_HELP, SEED, bundled_cell, emit


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..calibration.suggest import write_suggested_config
    from ..data.dataset import load_dataset
    from ..simulation.cell import load_cell
    from ..simulation.simulate import simulate

    result = simulate(
        bundled_cell(args.cell),
        args.out,
        args.seed,
        design=args.design,
        n_configurations=args.n,
        progress=Reporter(),
        render=args.render,
        drift=_parse_drift(args.drift),
        configurations=args.configurations,
    )
    say(result.summary())
    config = write_suggested_config(load_cell(bundled_cell(args.cell)), load_dataset(args.out))
    say(f"  calibration config: {config} (fgcal calibrate {config} --out REPORT)")
    emit(args, {
        "dataset": str(result.out_dir), "calibration_config": str(config), "seed": result.seed,
        "design": result.design, "n_configurations": result.n_configurations, "observations": result.n_observations,
        "nominal_deviation_mean_m": result.deviation_mean_m, "nominal_deviation_max_m": result.deviation_max_m,
        "time_s": result.time_s,
    })  # fmt: skip
    return 0


def _parse_drift(text: str | None):
    from ..core.errors import InputError
    from ..simulation.simulate import Drift

    if text is None:
        return None
    try:
        name, rest = text.split("=", 1)
        value, start = rest.split("@", 1)
        drift = Drift(name.strip(), float(value), int(start))
    except ValueError:
        raise InputError(None, "--drift", f"expected NAME=CHANGE@CONFIGURATION (SI units), got {text!r}") from None
    if not (np.isfinite(drift.change) and abs(drift.change) <= 1.0):
        raise InputError(None, "--drift", f"the change is a step of at most 1 (m or rad), got {drift.change:g}")
    return drift


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a calibration cell: true robot, configurations, measurements")
    p.add_argument("cell", help="cell YAML file, or a bundled cell name (kr125_seed)")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.add_argument("--seed", type=SEED, default=1, help="random seed (default 1); same seed, same files")
    p.add_argument("--design", choices=("seed", "space_filling"), help="override the cell's design kind")
    p.add_argument(
        "--n",
        type=CONFIGURATIONS,
        help=f"number of configurations of a space-filling design (1 to {MAX_CONFIGURATIONS})",
    )
    p.add_argument(
        "--configurations", help="CSV of configurations (config, q1..qn, block) to simulate exactly, e.g. fgcal plan's"
    )
    p.add_argument("--render", action="store_true", help="also render the camera images (ChArUco boards)")
    p.add_argument(
        "--drift", help="step change of a true parameter under the camera or tracker readings, NAME=CHANGE@CONFIG (SI)"
    )
    p.add_argument("--json", action="store_true", help=JSON_HELP)
    p.set_defaults(func=cmd_simulate)
