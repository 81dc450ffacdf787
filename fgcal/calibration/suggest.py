"""The calibration config that a simulated cell's dataset suggests, written beside it by
``fgcal simulate`` (``calibration.yaml``): the formulation that reads the cell's own
instrument, the extended model (with the motion history's terms when the cell's robot has
lost motion), the compliant joints of the cell's true robot, and the noise
its instruments state (the dataset's)."""

from __future__ import annotations

from pathlib import Path

import yaml

from ..core.errors import InputError
from ..core.noise import noise_document
from ..core.outputs import write_text
from ..data.dataset import Dataset
from ..simulation.cell import Cell
from .formulations import REGISTRY


def suggested_formulation(cell: Cell) -> str:
    """The first registered formulation that reads the cell's first instrument (its own)."""
    for instrument in cell.instruments:
        for name, cls in REGISTRY.items():
            if cls.instrument == instrument:
                return name
    raise InputError(cell.source, None, "the cell has no instrument a formulation reads")


def suggested_config(cell: Cell, dataset: Dataset) -> dict:
    joints = [j for j in cell.perturbation.compliant_joints if j <= dataset.robot.n_links]
    return {
        "dataset": ".",
        "formulation": suggested_formulation(cell),
        "model": "DH,s,e,h" if cell.motion is not None else "DH,s,e",
        "compliant_joints": joints,
        "noise": noise_document(dataset.noise),
    }


def write_suggested_config(cell: Cell, dataset: Dataset) -> Path:
    """``calibration.yaml`` in the dataset's directory (its path)."""
    path = Path(dataset.path) / "calibration.yaml"
    note = (
        f"# Suggested by fgcal simulate for {Path(cell.source).name}: the formulation of the cell's instrument, the\n"
        "# compliant joints of its true robot and the noise its instruments state. docs/calibration.md\n"
    )
    write_text(path, note + yaml.safe_dump(suggested_config(cell, dataset), sort_keys=False))
    return path
