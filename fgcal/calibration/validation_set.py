"""A separate validation set: another dataset of the same robot and instrument whose
configurations are all held out (``validation: {dataset: DIR}`` in the config).

Its configurations and measurement tables are appended to the fitting dataset's, their ids
prefixed with ``validation/``; the problem then holds them out like any held-out
configuration and scores them like the fitting data. A tool point measured only in the
validation set (a test point on the tool that the fit never saw) is declared in the config
(``validation.tool_points``) or fitted leave-one-out (fgcal.calibration.formulations.tracker).
"""

from __future__ import annotations

import copy

import numpy as np

from ..dataset import Dataset, Table, load_dataset
from ..errors import InputError
from .config import CalibrationConfig

PREFIX = "validation/"
# Tables that describe the cell rather than measure at configurations, and must agree.
SHARED = ("points", "point_distances")
# Session checks that belong to the session that measured them.
SESSION_ONLY = ("tracker_references",)
# Id columns that name a configuration (a distance between configurations has two).
CONFIG_COLUMNS = ("config", "config_a", "config_b")


def with_validation_set(dataset: Dataset, config: CalibrationConfig) -> tuple[Dataset, np.ndarray]:
    """The dataset with the validation set appended, and the indices of its configurations."""
    path = config.validation_dataset
    other = load_dataset(path)
    where = config.path
    if other.robot.name != dataset.robot.name or other.robot.n_joints != dataset.robot.n_joints:
        raise InputError(
            where,
            "validation.dataset",
            f"{path} measures {other.robot.name} ({other.robot.n_joints} joints), the fitting set "
            f"{dataset.robot.name} ({dataset.robot.n_joints} joints): a validation set measures the same robot",
        )
    merged = copy.copy(dataset)
    merged.configs = np.concatenate([dataset.configs, [PREFIX + str(c) for c in other.configs]]).astype(object)
    merged.q = np.vstack([dataset.q, other.q])
    merged.tables = dict(dataset.tables)
    for name, table in other.tables.items():
        if name in SESSION_ONLY:
            continue
        if name in SHARED:
            _check_shared(dataset, other, name, where)
            merged.tables.setdefault(name, table)
            continue
        ids = {k: (np.array([PREFIX + str(c) for c in v], dtype=object) if k in CONFIG_COLUMNS else v)
               for k, v in table.ids.items()}  # fmt: skip
        mine = dataset.tables.get(name)
        if mine is None:
            merged.tables[name] = Table(ids, table.values)
        else:
            merged.tables[name] = Table(
                {k: np.concatenate([mine.ids[k], ids[k]]).astype(object) for k in mine.ids},
                np.vstack([mine.values, table.values]),
            )
    return merged, np.arange(len(dataset.configs), len(merged.configs))


def _check_shared(dataset: Dataset, other: Dataset, name: str, where) -> None:
    """Points both sets name must be the same points (the same drawing)."""
    mine = dataset.tables.get(name)
    if mine is None or name != "points":
        return
    positions = dict(zip(mine.ids["point"], mine.values, strict=True))
    for point, xyz in zip(other.tables[name].ids["point"], other.tables[name].values, strict=True):
        if point in positions and not np.allclose(positions[point], xyz, atol=1e-9):
            raise InputError(
                where,
                "validation.dataset",
                f"point {point!r} has other coordinates in the validation set's points table than in the fitting set's",
            )
