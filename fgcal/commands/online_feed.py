"""``fgcal online-feed``: a dataset's images written as measurement files into an inbox."""

from __future__ import annotations

import argparse

from ..core.console import say
from .options import integer


def cmd_online_feed(args: argparse.Namespace) -> int:
    from ..online.feed import feed_dataset

    written = feed_dataset(args.dataset, args.inbox, args.first, args.n, args.cycle_size)
    say(f"wrote {written} measurement files to {args.inbox}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("online-feed", help="write a dataset's images as measurement files into an inbox")
    p.add_argument("dataset", help="dataset directory with pixels")
    p.add_argument("--inbox", required=True, help="the inbox folder fgcal online watches (created)")
    p.add_argument(
        "--first", type=integer(0, 10**9, "configurations"), default=0, help="first configuration (default 0)"
    )
    p.add_argument("--n", type=integer(1, 10**9, "images"), help="number of images (default all)")
    p.add_argument("--cycle-size", type=integer(1, 10**9, "images"), help="images per work cycle (default: no cycles)")
    p.set_defaults(func=cmd_online_feed)
