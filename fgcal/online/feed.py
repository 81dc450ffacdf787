"""Turn a dataset's configurations into inbox measurement files (for demos, tests and replays)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..data.dataset import load_dataset
from .measurement import Measurement, write_measurement


def dataset_measurements(dataset_dir: str | Path, cycle_size: int | None = None) -> list[Measurement]:
    """One measurement per configuration of the dataset with observations: every table of
    the dataset indexed by configuration (a pixels table as ``pixels``), and how the
    configuration was reached when the dataset says (its motion history). A reading between
    two configurations (a table whose ids name both, config_a and config_b, as tool_distances)
    goes with the later of the two; the configurations then carry their ids as labels, and one
    that only such readings name is a measurement of its own without observations."""
    dataset = load_dataset(dataset_dir)
    measured = {name: table for name, table in dataset.tables.items() if "config" in table.ids}
    between = {name: t for name, t in dataset.tables.items() if "config" not in t.ids and _refers(t.ids)}
    if not measured and not between:
        raise InputError(dataset_dir, "measured", "the dataset has no table of a configuration's measurements")
    rows: dict[str, dict[str, np.ndarray]] = {name: {} for name in measured}
    for name, table in measured.items():
        configs = np.asarray(table.ids["config"])
        for config in dict.fromkeys(configs.tolist()):
            rows[name][config] = np.flatnonzero(configs == config)
    position = {c: j for j, c in enumerate(dataset.configs)}
    later: dict[str, dict[str, list[int]]] = {name: {} for name in between}
    named: set[str] = set()
    for name, table in between.items():
        for i in range(len(table.values)):
            ends = [str(table.ids[k][i]) for k in _refers(table.ids)]
            named.update(ends)
            later[name].setdefault(max(ends, key=position.__getitem__), []).append(i)
    history = dataset.motion_history
    known = history.known()
    out = []
    for j, config in enumerate(dataset.configs):
        pixels, observations = (), []
        for name, table in measured.items():
            mine = rows[name].get(config)
            if mine is None:
                continue
            if name == "pixels":  # the short form of the camera's table
                pixels = tuple(zip(table.ids["point"][mine].tolist(), table.values[mine], strict=True))
                continue
            ids = {k: tuple(str(v) for v in column[mine]) for k, column in table.ids.items() if k != "config"}
            observations.append((name, ids, table.values[mine]))
        for name, table in between.items():
            mine = np.array(later[name].get(config, []), dtype=int)
            if len(mine):
                observations.append((name, {k: tuple(str(v) for v in c[mine]) for k, c in table.ids.items()},
                                     table.values[mine]))  # fmt: skip
        if not pixels and not observations and config not in named:
            continue
        out.append(
            Measurement(
                f"{j:06d}_{config}.json",
                dataset.q[j],
                pixels,
                None if cycle_size is None else j // cycle_size,
                tuple(observations),
                history.before[j] if known[j] else None,
                float(history.speed[j]) if dataset.history is not None else None,
                label=str(config) if between else None,
            )
        )
    return out


def _refers(ids) -> list[str]:
    """The id columns that name configurations (a reading between two)."""
    return [k for k in ids if k.startswith("config_")]


def feed_dataset(
    dataset_dir: str | Path, inbox: str | Path, first: int = 0, n: int | None = None, cycle_size: int | None = None
) -> int:
    if cycle_size is not None and cycle_size < 1:
        raise InputError(None, "--cycle-size", f"must be >= 1, got {cycle_size}")
    every = dataset_measurements(dataset_dir, cycle_size)
    if first >= len(every):
        raise InputError(None, "--first", f"the dataset has {len(every)} images (0 to {len(every) - 1}), got {first}")
    measurements = every[first:]
    if n is not None:
        measurements = measurements[:n]
    for measurement in measurements:
        write_measurement(inbox, measurement)
    return len(measurements)
