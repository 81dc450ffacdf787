"""``fgcal import-csv MAPPING``: tracker, probe or ballbar exports as an fgcal dataset."""

from __future__ import annotations

import argparse

from .options import converted


def cmd_import_csv(args: argparse.Namespace) -> int:
    from ..data.csv_import import import_tables

    converted(args.out, import_tables(args.mapping, args.out), "fgcal import-csv")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import-csv", help="convert tracker, probe or ballbar exports (CSV, text) to a dataset (docs/formats.md)"
    )
    p.add_argument("mapping", help="mapping YAML (format: fgcal-import/1): files, columns, units")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_import_csv)
