"""Converter for the ABB IRB 120 / FARO laser tracker data set (icelinker layout).

Input folder: ``measured_joints.txt`` (N x 6 joint angles, deg), ``measured_SMR_{k}.txt``
(N x 3, mm, tracker frame: reflectors on the tool) and optionally ``measured_base_{k}.txt``
(N x 3, mm: reflectors fixed in the cell; a row of zeros means "not found").
Output: an fgcal dataset (mm, deg, as measured) with ``tracker_points`` and
``tracker_references``; no value is altered, rows of zeros are dropped. The conversion is the
generic importer (:mod:`fgcal.data.csv_import`) with this layout's mapping.
"""

from __future__ import annotations

from pathlib import Path

from ..core.errors import InputError
from .csv_import import import_mapping
from .schema import IMPORT_FORMAT


def faro_mapping(src: Path, robot: str = "abb_irb120") -> dict:
    """The import mapping of the layout: headerless whitespace tables joined by row."""

    def targets(pattern: str, prefix: str) -> list[dict]:
        return [
            {
                "file": path.name,
                "header": False,
                "delimiter": "whitespace",
                "target_name": f"{prefix}{path.stem.rsplit('_', 1)[-1]}",
                "xyz": [1, 2, 3],
                "zeros_mean_not_found": True,
            }
            for path in sorted(src.glob(pattern))
        ]

    mapping = {
        "format": IMPORT_FORMAT,
        "robot": robot,
        "units": {"length": "mm", "angle": "deg"},
        "configurations": {
            "file": "measured_joints.txt",
            "header": False,
            "delimiter": "whitespace",
            "joints": [1, 2, 3, 4, 5, 6],
        },
        "tracker_points": targets("measured_SMR_*.txt", "smr"),
        "source": "FARO laser tracker, ABB IRB 120; rows of zeros (reflector not found) dropped; values as "
        "measured (outliers are kept: the estimator's robust losses deal with them)",
    }
    references = targets("measured_base_*.txt", "ref")
    if references:
        mapping["tracker_references"] = references
    return mapping


def convert_faro(src: str | Path, out: str | Path, robot: str = "abb_irb120") -> dict[str, int]:
    """Write the dataset; returns row counts (and dropped rows) for the summary."""
    src = Path(src)
    if not (src / "measured_joints.txt").exists():
        raise InputError(src / "measured_joints.txt", None, "file not found")
    mapping = faro_mapping(src, robot)
    if not mapping["tracker_points"]:
        raise InputError(src, None, "no measured_SMR_*.txt files (reflectors on the tool)")
    return import_mapping(mapping, f"{src} (FARO layout)", src, out, f"fgcal convert-faro {src.name}")
