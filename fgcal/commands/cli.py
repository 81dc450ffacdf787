"""The ``fgcal`` command: its parser, built from one module per command, and the error boundary.
Errors in user input print one clear line and exit with 2; anything else is a bug (traceback, 1)."""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from typing import NoReturn

from ..core.errors import FgcalError
from . import (
    bench,
    calibrate,
    compensate,
    convert_faro,
    demo,
    export,
    fk,
    import_csv,
    listing,
    online,
    online_feed,
    plan,
    schema,
    simulate,
)

# In the order of ``fgcal --help``; each module registers its subcommand(s) and their handler.
COMMANDS = (
    simulate, calibrate, demo, bench, compensate, online, online_feed, convert_faro, import_csv, plan, export,
    listing, fk, schema,
)  # fmt: skip


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line, like every other error: ``fgcal: error: ...``, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"fgcal: error: {self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="fgcal", description="Robot calibration with factor graphs (GTSAM).")
    parser.add_argument("--version", action="version", version=f"fgcal {_version()}")
    _verbosity(parser, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(sub)
    for command in sub.choices.values():  # fgcal -q calibrate ... and fgcal calibrate ... -q alike
        _verbosity(command, argparse.SUPPRESS)  # only when given: -q before the command is kept
    return parser


def _verbosity(parser: argparse.ArgumentParser, default) -> None:
    parser.add_argument("-q", "--quiet", action="count", default=default, help="only warnings and errors")
    parser.add_argument("-v", "--verbose", action="count", default=default, help="more detail")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fgcal")
    except PackageNotFoundError:  # a source tree without an install
        return "unknown (not installed)"


def main(argv: list[str] | None = None) -> int:
    from ..core.console import setup

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed
        return exc.code if isinstance(exc.code, int) else 2
    setup(getattr(args, "verbose", 0) - getattr(args, "quiet", 0), to_stderr=getattr(args, "json", False))
    from threadpoolctl import threadpool_limits

    try:
        # fgcal's dense algebra is small (tens of columns): one BLAS thread is fastest, and
        # threads would stall each other on a busy machine.
        with threadpool_limits(limits=1, user_api="blas"):
            return args.func(args)
    except FgcalError as exc:  # the user's input: one line naming the file and field
        print(f"fgcal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (| head): stop quietly, as a shell tool does
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (the interpreter's last flush must not fail)
        return 141
    except Exception:  # a bug of fgcal's, never dressed as the user's
        print("fgcal: internal error (please report it with the traceback below)", file=sys.stderr)
        traceback.print_exc()
        return 1


if __name__ == "__main__":
    sys.exit(main())
