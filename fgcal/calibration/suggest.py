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
from ..core.units import Units, parse_units
from ..data.dataset import Dataset
from ..simulation.cell import Cell
from .formulations import REGISTRY, from_measured


def suggested_formulation(cell: Cell) -> str:
    """The first registered formulation that reads the cell's first instrument (its own)."""
    for instrument in cell.instruments:
        for name, cls in REGISTRY.items():
            if cls.instrument == instrument:
                return name
    raise InputError(cell.source, None, "the cell has no instrument a formulation reads")


def _units(dataset: Dataset) -> Units:
    return parse_units(dataset.header.get("units"), Path(dataset.path) / "dataset.yaml")


def _read_noise(formulation: str, noise: dict) -> dict:
    """The noise entries the formulation reads (a cell's other instruments' stay in the dataset:
    stated in the config they would be said to have no effect)."""
    read = REGISTRY[formulation].settings_read
    return {key: value for key, value in noise.items() if f"noise.{key}" in read}


def _reader(instrument: str) -> str | None:
    """The first registered formulation that reads an instrument."""
    return next((name for name, cls in REGISTRY.items() if cls.instrument == instrument), None)


def suggested_config(cell: Cell, dataset: Dataset) -> dict:
    """One formulation, that of the cell's own instrument; or, in a cell that names instruments
    for validation only, one set per instrument (docs/calibration.md, "Several measurement
    sets"): the others fitted together, those scored (use: validation)."""
    joints = [j for j in cell.perturbation.compliant_joints if j <= dataset.robot.n_links]
    units = _units(dataset)
    noise = noise_document(dataset.noise, units)
    common = {
        "dataset": ".",
        "model": "DH,s,e,h" if cell.motion is not None else "DH,s,e",
        "compliant_joints": joints,
        "units": {"length": units.length, "angle": units.angle},
    }
    if not cell.validation:
        formulation = suggested_formulation(cell)
        return {"dataset": ".", "formulation": formulation, **common, "noise": _read_noise(formulation, noise)}
    sets = []
    for instrument in cell.instruments:
        formulation = _reader(instrument)
        if formulation is None:
            continue
        entry = {"name": instrument, "formulation": formulation}
        if instrument in cell.validation:
            entry["use"] = "validation"
        own = _read_noise(formulation, noise)
        if own:
            entry["noise"] = own
        sets.append(entry)
    return {**common, "sets": sets}


def dataset_config(dataset: Dataset) -> dict:
    """The config of a dataset converted from an instrument's files (no cell behind it): the
    formulation that reads what it measured, the extended model, its units, and the noise the
    instrument states (fgcal's defaults where it states none)."""
    units = _units(dataset)
    readers = from_measured(list(dataset.tables), dataset.camera_mounting is not None)
    if not readers:
        raise InputError(dataset.path, "measured", "no measured table a formulation reads")
    config = {"dataset": ".", "formulation": readers[0], "model": "DH,s,e",
              "units": {"length": units.length, "angle": units.angle}}  # fmt: skip
    noise = _read_noise(readers[0], noise_document(dataset.noise, units)) if dataset.noise else {}
    if noise:
        config["noise"] = noise
    return config


def write_dataset_config(dataset: Dataset, command: str) -> Path:
    """``calibration.yaml`` beside a converted dataset (its path), as fgcal simulate writes one."""
    path = Path(dataset.path) / "calibration.yaml"
    config = dataset_config(dataset)
    note = (
        f"# Written by {command}: the formulation that reads what the dataset measured, the extended\n"
        "# model DH,s,e (model: auto would fit DH to DH,s,e,h and keep what the data support), lengths and\n"
        "# angles in the dataset's units. State your instrument's noise (noise: in these units;\n"
        "# docs/calibration.md):\n"
        "# the report warns when it and the residuals differ by more than 10x.\n"
    )
    write_text(path, note + yaml.safe_dump(config, sort_keys=False))
    return path


def write_suggested_config(cell: Cell, dataset: Dataset) -> Path:
    """``calibration.yaml`` in the dataset's directory (its path)."""
    path = Path(dataset.path) / "calibration.yaml"
    note = (
        f"# Suggested by fgcal simulate for {Path(cell.source).name}: the formulation of the cell's instrument (or a\n"
        "# set per instrument, those the cell measures for validation only scored), the compliant joints of its\n"
        "# true robot and the noise its instruments state. docs/calibration.md\n"
    )
    write_text(path, note + yaml.safe_dump(suggested_config(cell, dataset), sort_keys=False))
    return path
