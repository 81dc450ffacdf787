"""``fgcal demo``: the seed cell simulated, self-calibrated and reported."""

from __future__ import annotations

import argparse

from ..core.console import Reporter, say
from .calibrate import score
from .options import CONFIGURATIONS, SEED, bundled_cell


def cmd_demo(args: argparse.Namespace) -> int:
    import dataclasses

    import yaml

    from ..calibration.config import load_config
    from ..calibration.run import calibrate
    from ..core.outputs import output_dir, write_text
    from ..reports.calibration import write_report
    from ..simulation.simulate import simulate

    out = output_dir(args.out)
    say(f"1/3 simulating the seed cell: space-filling design of {args.n} configurations, seed {args.seed}")
    sim = simulate(
        bundled_cell("kr125_seed"),
        out / "data",
        args.seed,
        design="space_filling",
        n_configurations=args.n,
        progress=Reporter(),
    )
    say(sim.summary())
    config_path = write_text(
        out / "calibration.yaml",
        yaml.safe_dump({"dataset": "data", "formulation": args.formulation, "model": "DH,s,e"}, sort_keys=False),
    )
    say(f"2/3 calibrating ({config_path})")
    result = score(calibrate(load_config(config_path), progress=Reporter()))
    if result.truth is not None:
        from ..calibration.scoring import compensation_study

        study = compensation_study(result)
        result = dataclasses.replace(result, compensation=study)
        say(
            f"  compensation of {study.n_targets} random targets, driven through the true robot: "
            f"{study.uncompensated_rms_m * 1e3:.4g} mm RMS with the nominal model's joints, "
            f"{study.compensated_rms_m * 1e3:.4g} mm with the calibrated model's ({study.improvement:.0f}x)"
        )
    say("3/3 writing the report")
    write_report(result, out / "report")
    say(f"report: {out / 'report' / 'report.md'}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate the seed cell, calibrate it and write the report")
    p.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    p.add_argument("--seed", type=SEED, default=1, help="simulation seed (default 1)")
    p.add_argument(
        "--n", type=CONFIGURATIONS, default=300, help="configurations of the space-filling design (default 300)"
    )
    p.add_argument(
        "--formulation", choices=("pairs", "tracker"), default="pairs", help="what to calibrate from (default pairs)"
    )
    p.set_defaults(func=cmd_demo)
