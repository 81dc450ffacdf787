"""``fgcal bench``: fgcal's solve against its yardsticks, and the online latency (fgcal.bench)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..core.console import say
from .options import SEED, integer


def cmd_bench(args: argparse.Namespace) -> int:
    from ..bench.suite import run_bench
    from ..core import strict_json

    sizes = tuple(args.sizes)
    # With --json, stdout carries the JSON object alone; the progress goes to stderr.
    faro = Path(args.faro) if args.faro else None
    if faro is not None and not (faro / "dataset.yaml").exists():
        print(
            f"fgcal: error: {faro}: no dataset.yaml (convert the FARO files with fgcal convert-faro)", file=sys.stderr
        )
        return 2
    if args.kinematics:
        from ..bench.kernel import kernel_bench

        say("fgcal bench --kinematics: the chain's FK and Jacobians against Pinocchio, issue 37's targets")
        result = kernel_bench(args.repeats, say)
    else:
        result = run_bench(
            Path(args.out), seed=args.seed, sizes=sizes, repeats=args.repeats, say=say, faro=faro,
            memory_n=args.memory_n, program_targets=args.program_targets,
        )  # fmt: skip
    if args.json:
        print(strict_json.dumps(result))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench", help="time fgcal's solve against a NumPy Gauss-Newton and scipy, and online latency (docs/cli.md)"
    )
    p.add_argument(
        "--out", default="out/bench", help="where the simulated cases are kept between runs (default out/bench)"
    )
    p.add_argument("--seed", type=SEED, default=1, help="simulation seed (default 1)")
    p.add_argument(
        "--sizes",
        type=integer(20, 20000, "configurations"),
        nargs="+",
        default=[300, 1000],
        help="configurations per case (default 300 1000)",
    )
    p.add_argument(
        "--repeats",
        type=integer(1, 100, "rounds"),
        default=3,
        help="interleaved rounds; the best of each is kept (default 3)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (SI units) on stdout")
    p.add_argument("--faro", help="a dataset from fgcal convert-faro: time the whole calibrate command on it too")
    p.add_argument(
        "--memory-n",
        type=integer(20, 20000, "configurations"),
        default=3000,
        help="configurations of the seed cell whose calibrate command's peak RSS is measured (default 3000)",
    )
    p.add_argument(
        "--program-targets",
        type=integer(40, 200000, "targets"),
        default=4000,
        help="targets of the KRL program and CSV whose CPU per target fgcal compensate is timed on (default 4000; "
        "a twentieth of them is the start-up's baseline)",
    )
    p.add_argument(
        "--kinematics",
        action="store_true",
        help="only the kinematics figures and issue 37's targets against Pinocchio (seconds, not minutes)",
    )
    p.set_defaults(func=cmd_bench)
