from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fgcal

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
SEED_CELL = REPO / "datasets" / "cells" / "kr125_seed.yaml"


def random_parameters(robot: fgcal.Robot, rng: np.random.Generator) -> dict[str, float]:
    """Nominal parameters with random deviations of every kind, compliances included."""
    params = robot.nominal_parameters()
    for name in params:
        kind = name.rstrip("0123456789")
        if kind in ("kx", "ky", "kz"):
            params[name] = rng.uniform(1e-6, 1e-5)
        elif kind in ("sx", "sy") or name.startswith(("base.r", "tool.r")):
            params[name] = rng.normal(0.0, 0.05)
        else:
            params[name] += rng.normal(0.0, 0.01)
    return params


@pytest.fixture(scope="session")
def seed_sim(tmp_path_factory) -> Path:
    """The bundled seed cell simulated once with seed 1."""
    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("seed_sim")
    simulate(SEED_CELL, out, seed=1)
    return out


def calibrate(config, progress=None):
    """fgcal.calibration.run.calibrate, then scored against the simulation's truth as the
    CLI does (when the dataset has one)."""
    from fgcal.calibration import run, scoring

    result = run.calibrate(config, progress)
    scoring.score_with_truth(result)
    return result


def calibrate_dataset(dataset, config, progress=None):
    """fgcal.calibration.run.calibrate_dataset, then scored against the truth (if any)."""
    from fgcal.calibration import run, scoring

    result = run.calibrate_dataset(dataset, config, progress)
    scoring.score_with_truth(result)
    return result
