"""Separate validation sets: other datasets of the same robot and instrument whose
configurations are all held out (``validation: {dataset: DIR}`` or ``{dataset: [DIR, ...]}``
in the config).

Their configurations and measurement tables are appended to the fitting dataset's, their ids
prefixed with ``validation/`` (``validation1/``, ``validation2/``, ... when there are several);
the problem then holds them out like any held-out
configuration and scores them like the fitting data. A tool point measured only in the
validation set (a test point on the tool that the fit never saw) is declared in the config
(``validation.tool_points``) or fitted leave-one-out (fgcal.calibration.formulations.tracker).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.dataset import Dataset, Table, load_dataset
from ..model.motion import MotionHistory
from .config import CalibrationConfig

PREFIX = "validation/"
# Tables that describe the cell rather than measure at configurations, and must agree.
SHARED = ("points", "point_distances")
# Session checks that belong to the session that measured them.
SESSION_ONLY = ("tracker_references",)
# Id columns that name a configuration (a distance between configurations has two).
CONFIG_COLUMNS = ("config", "config_a", "config_b")


def prefix(k: int, count: int) -> str:
    """The configuration-id prefix of validation set ``k`` of ``count``."""
    return PREFIX if count == 1 else f"validation{k + 1}/"


def with_validation_sets(dataset: Dataset, config: CalibrationConfig) -> tuple[Dataset, list[tuple[str, np.ndarray]]]:
    """The dataset with every validation set appended, and per set its directory and the
    indices of its configurations."""
    sets = []
    for k, path in enumerate(config.validation_datasets):
        start = len(dataset.configs)
        dataset = with_validation_set(dataset, path, config, prefix(k, len(config.validation_datasets)))
        sets.append((str(path), np.arange(start, len(dataset.configs))))
    named = {
        str(name) for t in dataset.tables.values() for k, v in t.ids.items() if k not in CONFIG_COLUMNS for name in v
    }
    for name in config.measurement.validation_tool_points:
        if name not in named:
            raise InputError(
                config.path, f"validation.tool_points.{name}", "no table of the data or its validation sets measures "
                "a point of this name",
            )  # fmt: skip
    return dataset, sets


def with_validation_set(dataset: Dataset, path, config: CalibrationConfig, id_prefix: str = PREFIX) -> Dataset:
    """The dataset with the validation set at ``path`` appended, its ids prefixed."""
    where = config.path
    if not (Path(path) / "dataset.yaml").is_file():
        raise InputError(where, "validation.dataset", f"no dataset at {path} (a folder with a dataset.yaml)")
    if Path(path).resolve() == Path(dataset.path).resolve():
        raise InputError(where, "validation.dataset", f"{path} is the fitting set: a validation set is another session")
    other = load_dataset(path)
    if other.robot.name != dataset.robot.name or other.robot.n_joints != dataset.robot.n_joints:
        raise InputError(
            where,
            "validation.dataset",
            f"{path} measures {other.robot.name} ({other.robot.n_joints} joints), the fitting set "
            f"{dataset.robot.name} ({dataset.robot.n_joints} joints): a validation set measures the same robot",
        )
    common = {n for n in other.tables if n not in SHARED} & {n for n in dataset.tables if n not in SHARED}
    if not common:
        raise InputError(
            where, "validation.dataset", f"{path} measures {', '.join(sorted(other.tables)) or 'nothing'}, the fitting "
            f"set {', '.join(sorted(dataset.tables))}: nothing to compare",
        )  # fmt: skip
    merged = copy.copy(dataset)
    merged.configs = np.concatenate([dataset.configs, [id_prefix + str(c) for c in other.configs]]).astype(object)
    merged.q = np.vstack([dataset.q, other.q])
    # Each session's configurations were reached in its own order.
    own, theirs = dataset.motion_history, other.motion_history
    merged.history = MotionHistory(np.vstack([own.before, theirs.before]), np.concatenate([own.speed, theirs.speed]))
    merged.tables = dict(dataset.tables)
    for name, table in other.tables.items():
        if name in SESSION_ONLY:
            continue
        if name in SHARED:
            _check_shared(dataset, other, name, where)
            merged.tables.setdefault(name, table)
            continue
        ids = {k: (np.array([id_prefix + str(c) for c in v], dtype=object) if k in CONFIG_COLUMNS else v)
               for k, v in table.ids.items()}  # fmt: skip
        mine = dataset.tables.get(name)
        if mine is None:
            merged.tables[name] = Table(ids, table.values)
        else:
            merged.tables[name] = Table(
                {k: np.concatenate([mine.ids[k], ids[k]]).astype(object) for k in mine.ids},
                np.vstack([mine.values, table.values]),
            )
    return merged


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
