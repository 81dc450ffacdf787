"""``fgcal convert-faro``: the IRB 120 / FARO tracker text files as an fgcal dataset."""

from __future__ import annotations

import argparse

from ..core.console import say


def cmd_convert_faro(args: argparse.Namespace) -> int:
    from ..calibration.suggest import write_dataset_config
    from ..data.dataset import load_dataset
    from ..data.faro import convert_faro

    counts = convert_faro(args.src, args.out)
    say(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    config = write_dataset_config(load_dataset(args.out), "fgcal convert-faro")
    say(f"  calibration config: {config} (fgcal calibrate {config} --out REPORT)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("convert-faro", help="convert the IRB 120 / FARO tracker text files to an fgcal dataset")
    p.add_argument("src", help="folder with measured_joints.txt and measured_SMR_*.txt")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_convert_faro)
