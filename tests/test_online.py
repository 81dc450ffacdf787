"""Online recalibration with iSAM2: incremental estimate equals the batch estimate."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import SEED_CELL

import fgcal
from fgcal.dataset import load_dataset
from fgcal.online import OnlineCalibrator
from fgcal.online.calibrator import P_KEY
from fgcal.simulation.simulate import simulate


@pytest.fixture(scope="module")
def stream(tmp_path_factory):
    out = tmp_path_factory.mktemp("online")
    # The acceptance case: 300 images of the seed cell (seed 1).
    simulate(SEED_CELL, out, seed=1, design="space_filling", n_configurations=300)
    dataset = load_dataset(out)
    points = dict(zip(dataset.tables["points"].ids["point"], dataset.tables["points"].values, strict=True))
    images: dict[str, list] = {}
    pixels = dataset.tables["pixels"]
    for cid, name, uv in zip(pixels.ids["config"], pixels.ids["point"], pixels.values, strict=True):
        images.setdefault(cid, []).append((name, uv))
    return dataset, points, [(dataset.q[j], images[c]) for j, c in enumerate(dataset.configs)]


def test_first_images_are_prior_dominated_not_errors(stream):
    dataset, points, images = stream
    calibrator = OnlineCalibrator(dataset.robot, dataset.camera, points)
    estimate = calibrator.add(*images[0])
    sigmas = calibrator.estimate().sigmas
    assert estimate.n_images == 1 and all(np.isfinite(v) for v in estimate.params.values())
    # One image of four points cannot say much about 60 parameters: most stay at their priors.
    assert np.median([sigmas[n] / s for n, s in zip(calibrator.released, calibrator.prior_sigmas, strict=True)]) > 0.9


def test_online_equals_batch(stream):
    dataset, points, images = stream
    calibrator = OnlineCalibrator(dataset.robot, dataset.camera, points)
    for q, observations in images:
        calibrator.add(q, observations)
    graph = gtsam.NonlinearFactorGraph()
    for factor in calibrator.prior_factors():
        graph.add(factor)
    for j, (_, observations) in enumerate(images):
        for factor in calibrator.image_factors(j, observations):
            graph.add(factor.factor)
    online = calibrator.isam.calculateEstimate()
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    batch = gtsam.LevenbergMarquardtOptimizer(graph, online, params).optimize()
    sigma = np.array([calibrator.estimate().sigmas[n] for n in calibrator.released])
    difference = np.abs(online.atVector(P_KEY) - batch.atVector(P_KEY)) / sigma
    assert difference.max() < 0.1, calibrator.released[int(np.argmax(difference))]
    # The images did their work where the data can: parameters without a redundant partner are
    # known far better than their priors. Redundant pairs (alpha2 with sx3, theta3 with sy4)
    # keep prior/sqrt(2) each: only their sum is determined.
    ratio = dict(zip(calibrator.released, sigma / calibrator.prior_sigmas, strict=True))
    assert all(ratio[name] < 0.02 for name in ("a1", "theta2", "a2", "kz2")), ratio
    assert 0.6 < ratio["alpha2"] < 0.8 and 0.6 < ratio["sx3"] < 0.8


def test_unknown_points_are_clear_errors(stream):
    dataset, points, images = stream
    calibrator = OnlineCalibrator(dataset.robot, dataset.camera, points)
    with pytest.raises(fgcal.InputError, match="unknown calibration point"):
        calibrator.add(images[0][0], [("Z+z_r00c00", np.array([10.0, 10.0]))])
    with pytest.raises(fgcal.InputError, match="6 joints"):
        calibrator.add(np.zeros(5), images[0][1])
