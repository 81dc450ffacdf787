"""Turn a dataset's images into inbox measurement files (for demos, tests and replays)."""

from __future__ import annotations

from pathlib import Path

from ..core.errors import InputError
from ..data.dataset import load_dataset
from .measurement import Measurement, write_measurement


def dataset_measurements(dataset_dir: str | Path, cycle_size: int | None = None) -> list[Measurement]:
    """One measurement per configuration of the dataset, from its pixels table."""
    dataset = load_dataset(dataset_dir)
    if "pixels" not in dataset.tables:
        raise InputError(dataset_dir, "pixels", "the dataset has no pixels table")
    pixels = dataset.tables["pixels"]
    by_config: dict[str, list] = {}
    for config, point, uv in zip(pixels.ids["config"], pixels.ids["point"], pixels.values, strict=True):
        by_config.setdefault(config, []).append((point, uv))
    return [
        Measurement(
            f"{j:06d}_{config}.json",
            dataset.q[j],
            tuple(by_config[config]),
            None if cycle_size is None else j // cycle_size,
        )
        for j, config in enumerate(dataset.configs)
        if config in by_config
    ]


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
