"""``fgcal import-csv MAPPING``: tracker, probe or ballbar exports as an fgcal dataset."""

from __future__ import annotations

import argparse

from ..core.console import say


def cmd_import_csv(args: argparse.Namespace) -> int:
    from ..calibration.suggest import write_dataset_config
    from ..data.csv_import import import_tables
    from ..data.dataset import load_dataset

    counts = import_tables(args.mapping, args.out)
    say(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    config = write_dataset_config(load_dataset(args.out), "fgcal import-csv")
    say(f"  calibration config: {config} (fgcal calibrate {config} --out REPORT)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import-csv", help="convert tracker, probe or ballbar exports (CSV, text) to a dataset (docs/formats.md)"
    )
    p.add_argument("mapping", help="mapping YAML (format: fgcal-import/1): files, columns, units")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_import_csv)
