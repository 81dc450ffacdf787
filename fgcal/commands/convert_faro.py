"""``fgcal convert-faro``: the IRB 120 / FARO tracker text files as an fgcal dataset."""

from __future__ import annotations

import argparse

from .options import converted


def cmd_convert_faro(args: argparse.Namespace) -> int:
    from ..data.faro import convert_faro

    converted(args.out, convert_faro(args.src, args.out), "fgcal convert-faro")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("convert-faro", help="convert the IRB 120 / FARO tracker text files to an fgcal dataset")
    p.add_argument("src", help="folder with measured_joints.txt and measured_SMR_*.txt")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_convert_faro)
