"""``fgcal online-feed``: a dataset's measurements written as files into an inbox, one configuration each."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from ..core.console import say
from ..core.errors import InputError
from .options import integer


def one_table(measurements: list, table: str, dataset: str | Path) -> list:
    """The measurements that carry ``table`` (a cell with several kinds feeds one formulation's
    per run: its measurement table), with that table's observations only."""
    out = []
    for m in measurements:
        observations = tuple(o for o in m.observations if o[0] == table)
        pixels = m.pixels if table == "pixels" else ()
        if observations or pixels:
            out.append(replace(m, pixels=pixels, observations=observations))
    if not out:
        raise InputError(dataset, "--table", f"the dataset has no table {table!r} of a configuration's measurements")
    return out


def feed(dataset: str | Path, inbox: str | Path, first: int = 0, n: int | None = None,
         cycle_size: int | None = None, table: str | None = None) -> int:  # fmt: skip
    """fgcal online-feed: every table of the dataset (fgcal.online.feed.feed_dataset), or one."""
    from ..online.feed import dataset_measurements, feed_dataset
    from ..online.measurement import write_measurement

    if table is None:
        return feed_dataset(dataset, inbox, first, n, cycle_size)
    if cycle_size is not None and cycle_size < 1:
        raise InputError(None, "--cycle-size", f"must be >= 1, got {cycle_size}")
    every = one_table(dataset_measurements(dataset, cycle_size), table, dataset)
    if first >= len(every):
        raise InputError(None, "--first", f"the dataset has {len(every)} configurations with {table} (0 to "
                         f"{len(every) - 1}), got {first}")  # fmt: skip
    chosen = every[first:] if n is None else every[first : first + n]
    for measurement in chosen:
        write_measurement(inbox, measurement)
    return len(chosen)


def cmd_online_feed(args: argparse.Namespace) -> int:
    written = feed(args.dataset, args.inbox, args.first, args.n, args.cycle_size, args.table)
    say(f"wrote {written} measurement files to {args.inbox}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "online-feed", help="write a dataset's measurements as files into an inbox, one configuration each"
    )
    p.add_argument("dataset", help="the dataset directory (a simulated cell's, or a measured one)")
    p.add_argument("--inbox", required=True, help="the inbox folder fgcal online watches (created)")
    p.add_argument(
        "--first", type=integer(0, 10**9, "configurations"), default=0, help="first configuration (default 0)"
    )
    p.add_argument("--n", type=integer(1, 10**9, "configurations"), help="number of configurations (default all)")
    p.add_argument(
        "--cycle-size",
        type=integer(1, 10**9, "configurations"),
        help="configurations per work cycle (default: no cycles)",
    )
    p.add_argument(
        "--table",
        help="only this table's observations, and the configurations that have it (default: every table). A cell "
        "with several kinds (dual_arm_selfcontained) feeds one formulation per run: its measurement table "
        "(contacts, plane_contacts, tip_distances, observed_pixels); --first and --n count those configurations",
    )
    p.set_defaults(func=cmd_online_feed)
