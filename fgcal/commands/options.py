"""What the commands share: argument types with their ranges and units, the bundled cells,
``--json`` output, and counted nouns."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..simulation import MAX_CONFIGURATIONS

JSON_HELP = "print one JSON object (SI units) on stdout; the lines go to stderr"


def bundled_cells() -> list[str]:
    from ..model.robot_io import robots_dir

    return sorted(p.stem for p in (robots_dir().parent / "cells").glob("*.yaml"))


def bundled_cell(path: str) -> Path:
    """A cell file as given (a path ending in .yaml), or a bundled cell's name such as
    ``kr125_seed``: a name without the suffix is a bundled cell, whatever local folder is
    called the same."""
    from ..core.errors import InputError
    from ..model.robot_io import robots_dir

    candidate = Path(path)
    if candidate.suffix in (".yaml", ".yml"):
        return candidate
    bundled = robots_dir().parent / "cells" / f"{path}.yaml"
    if bundled.exists():
        return bundled
    if candidate.is_file():
        return candidate
    raise InputError(path, None, f"no such cell file or bundled cell (bundled: {', '.join(bundled_cells())})")


def emit(args: argparse.Namespace, document: dict) -> None:
    """With --json: the command's one strict JSON object (SI units) on stdout."""
    if getattr(args, "json", False):
        from ..core import strict_json

        print(strict_json.dumps({"command": args.command, **document}))


def integer(low: int, high: int, what: str) -> Callable[[str], int]:
    """An argparse type: a whole number of ``what`` from ``low`` to ``high``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number of {what}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{low} to {high} {what}, got {value}")
        return value

    return parse


def real(low: float, high: float, unit: str, *, above_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [low, high] (``above_low``: in (low, high])."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number ({unit}), got {text!r}") from None
        inside = (value > low if above_low else value >= low) and value <= high
        if not (np.isfinite(value) and inside):
            bracket = "(" if above_low else "["
            raise argparse.ArgumentTypeError(f"a number in {bracket}{low:g}, {high:g}] {unit}, got {text}")
        return value

    return parse


SEED = integer(0, 2**32 - 1, "(the random seed)")
LENGTH_M = real(-10.0, 10.0, "m")
CONFIGURATIONS = integer(1, MAX_CONFIGURATIONS, "configurations")


def converted(out: str, counts: dict, command: str) -> None:
    """After a converter wrote a dataset: its row counts, and the calibration config written
    beside it (the formulation reading what it measured, in its units), as simulate does."""
    from ..calibration.suggest import write_dataset_config
    from ..core.console import say
    from ..data.dataset import load_dataset

    say(f"wrote {out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    config = write_dataset_config(load_dataset(out), command)
    say(f"  calibration config: {config} (fgcal calibrate {config} --out REPORT)")


def count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def add_package_option(p: argparse.ArgumentParser) -> None:
    """``--package``: where a xacro's ``$(find PKG)`` is, without ROS (fgcal.model.xacro_io)."""
    p.add_argument(
        "--package",
        action="append",
        metavar="[NAME=]PATH",
        help="a ROS package's folder, for a xacro's $(find NAME) (PATH alone: the package named as its folder); "
        "repeat for each. Default: a folder of that name that holds the xacro or sits beside one that does",
    )


def xacro_packages(args: argparse.Namespace):
    """The context in which a xacro read by the command finds the packages of ``--package``."""
    from ..model.xacro_io import packages, parse_packages

    return packages(parse_packages(getattr(args, "package", None)))


def payload_com(given: list[float], to_m: float, robot) -> np.ndarray:
    """--payload-com in metres: given in --length-unit (a program's: m). A centre of mass farther
    from the flange than the arm reaches is a unit slip (mm typed for m), refused."""
    from ..core.errors import InputError

    com = np.array(given, dtype=float) * to_m
    reach = robot.reach_m()[1]
    if np.linalg.norm(com) > reach:
        unit = "mm" if to_m == 1e-3 else "m"
        raise InputError(None, "--payload-com", f"{' '.join(map(str, given))}: {np.linalg.norm(com):.3g} m from the "
                         f"flange, beyond the arm's reach ({reach:.3g} m); it is in {unit}")  # fmt: skip
    return com
