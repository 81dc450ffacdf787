"""Issue 25: the robot's motion history in the model (fgcal.motion): lost motion and a speed
term per joint, in the datasets, the simulator, the calibration and the compensation."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED

from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.run import calibrate
from fgcal.calibration.scoring import compensation_study, score_with_truth
from fgcal.dataset import load_dataset
from fgcal.errors import InputError
from fgcal.motion import LOST_MOTION_WIDTH_RAD, MotionHistory, features
from fgcal.reports.calibration import write_report
from fgcal.simulation.simulate import simulate
from fgcal.truth import load_truth

DATASETS = Path(__file__).resolve().parent.parent / "datasets"
LOST_MOTION_CELL = DATASETS / "cells" / "irb120_tracker_lost_motion.yaml"
MOTION_NAMES = [f"{kind}{i}" for kind in ("lm", "lv") for i in range(1, 7)]


def test_features_follow_the_last_move():
    q = np.radians([[0.0, 0.0], [10.0, -5.0], [10.0, -4.0], [10.0, -4.0]])
    motion = features(q, MotionHistory.in_order(q))
    # The first configuration's history is unknown; the last was not moved to: no offsets.
    assert np.all(motion[0] == 0.0) and np.all(motion[3] == 0.0)
    # Lost motion: the direction of each joint's move, taken up over 1 deg of travel.
    np.testing.assert_allclose(motion[1, :2], np.tanh(np.radians([10.0, -5.0]) / LOST_MOTION_WIDTH_RAD))
    np.testing.assert_allclose(motion[2, :2], [0.0, np.tanh(1.0)])
    # Speed: each joint's share of the largest move (a synchronised joint move).
    np.testing.assert_allclose(motion[1, 2:], [1.0, -0.5])
    np.testing.assert_allclose(motion[2, 2:], [0.0, 1.0])
    half = features(q, MotionHistory.in_order(q, speed=np.full(4, 0.5)))
    np.testing.assert_allclose(half[1, 2:], [0.5, -0.25])


@pytest.fixture(scope="module")
def lost_motion_cell(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("lost_motion")
    simulate(LOST_MOTION_CELL, out, seed=3)
    return out


@pytest.fixture(scope="module")
def calibrated(lost_motion_cell):
    return score_with_truth(calibrate(CalibrationConfig.defaults(lost_motion_cell, formulation="tracker",
                                                                 model="DH,s,e,h")))  # fmt: skip


def test_the_simulated_lost_motion_is_recovered_within_three_sigma(calibrated):
    result = calibrated
    names = result.problem.robot.parameter_names
    truth = result.truth.parameters
    sigmas = dict(zip(result.released, np.sqrt(np.diag(result.parameter_covariance)), strict=True))
    assert set(MOTION_NAMES) <= set(result.released)
    for name in MOTION_NAMES:
        estimate = result.state.params[names.index(name)]
        assert abs(estimate - truth[name]) < 3 * sigmas[name], (name, estimate, truth[name], sigmas[name])
    # The terms are real: each joint's speed term of 0.05-0.09 deg stands far above its sigma.
    assert all(truth[f"lv{i}"] > 10 * sigmas[f"lv{i}"] for i in (1, 2, 3))


def test_the_held_out_score_is_predicted_and_beats_the_static_model(calibrated, lost_motion_cell):
    after = calibrated.validation["after"]["tool_point"].rms
    assert 1 / 1.5 <= after / calibrated.prediction.rms <= 1.5, (after, calibrated.prediction.rms)
    static = score_with_truth(calibrate(CalibrationConfig.defaults(lost_motion_cell, formulation="tracker")))
    # Without the terms, the lost motion stays in the error: tens of times the noise-limited result.
    assert static.validation["after"]["tool_point"].rms > 20 * after


def test_compensation_allows_for_the_approach(calibrated):
    """Targets in sequence, driven through the simulated true robot (which reaches each from the
    one before): the commands that allow for the approach land within 1.5x the held-out RMS,
    those that do not are measurably worse."""
    study = compensation_study(calibrated, n_targets=200, seed=0)
    held_out = calibrated.validation["after"]["tool_point"].rms
    assert study.n_scored >= 150
    assert study.compensated_rms_m <= 1.5 * held_out, (study.compensated_rms_m, held_out)
    assert study.without_approach_rms_m > 10 * study.compensated_rms_m, study.as_dict()


def test_a_one_sided_design_is_told_it_cannot_identify_the_terms(tmp_path):
    cell = tmp_path / "one_sided.yaml"
    text = LOST_MOTION_CELL.read_text().replace("approach: previous", "approach: from_below")
    cell.write_text(text.replace("n_configurations: 200", "n_configurations: 100"))
    simulate(cell, tmp_path / "data", seed=3)
    assert "before_q1" in (tmp_path / "data" / "configurations.csv").read_text().splitlines()[0]
    result = calibrate(CalibrationConfig.defaults(tmp_path / "data", formulation="tracker", model="DH,s,e,h"))
    assert not set(MOTION_NAMES) & set(result.released)
    doc = write_report(result, tmp_path / "report", plots=False)
    warning = doc["motion_history_warning"]
    assert warning and "lm1" in warning and "one side" in warning
    assert "theta2" in warning  # what absorbs them is named
    assert "**Warning:**" in (tmp_path / "report" / "report.md").read_text()
    json.loads((tmp_path / "report" / "report.json").read_text())


def test_dataset_history_columns(tmp_path):
    data = tmp_path / "data"
    simulate(LOST_MOTION_CELL, data, seed=1, n_configurations=10)
    path = data / "configurations.csv"
    lines = path.read_text().splitlines()
    header = lines[0] + "," + ",".join(f"before_q{i}" for i in range(1, 7)) + ",speed"
    body = [line + "," * 6 + ",1" for line in lines[1:]]
    body[4] = lines[5] + ",0.1,0.2,0.3,0.4,0.5,0.6,0.5"
    path.write_text("\n".join([header, *body]) + "\n")
    dataset = load_dataset(data)
    history = dataset.motion_history
    assert np.isnan(history.before[0]).all()  # the first: unknown
    np.testing.assert_allclose(history.before[3], dataset.q[2])  # empty cells: the previous row
    np.testing.assert_allclose(history.before[4], [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])  # rad, the dataset's unit
    assert history.speed[4] == 0.5 and history.speed[3] == 1.0
    # A dataset whose rows are not in measurement order has no history.
    yaml_path = data / "dataset.yaml"
    yaml_path.write_text(yaml_path.read_text() + "order: unknown\n")
    assert np.all(load_dataset(data).motion[:4] == 0.0)


@pytest.mark.parametrize(
    "change, field",
    [
        (lambda h, r: (h + ",before_q1,before_q2", [x + ",1,2" for x in r]), "header"),
        (lambda h, r: (h + ",speed", [x + ",0" for x in r]), "column speed"),
        (lambda h, r: (h + ",speed", [x + ",nan" for x in r]), "column speed"),
        (
            lambda h, r: (h + "," + ",".join(f"before_q{i}" for i in range(1, 7)), [x + ",1,,,,," for x in r]),
            "line 2",
        ),
    ],
)
def test_bad_history_columns_name_the_file_and_field(tmp_path, change, field):
    data = tmp_path / "data"
    simulate(LOST_MOTION_CELL, data, seed=1, n_configurations=5)
    path = data / "configurations.csv"
    lines = path.read_text().splitlines()
    header, rows = change(lines[0], lines[1:])
    path.write_text("\n".join([header, *rows]) + "\n")
    with pytest.raises(InputError) as error:
        load_dataset(data)
    assert "configurations.csv" in str(error.value) and field in str(error.value)


def test_the_truth_declares_the_terms(lost_motion_cell):
    truth = load_truth(lost_motion_cell)
    assert truth.model == "DH,s,e,h"
    assert truth.parameters["lv1"] == pytest.approx(np.radians(0.09))
    assert truth.parameters["lm4"] == pytest.approx(np.radians(0.015))


FARO = SHARED / "data" / "irb120_faro"


@pytest.mark.skipif(not FARO.exists(), reason="../shared/data/irb120_faro is not present")
def test_real_faro_set_with_the_motion_terms_on_both_halves(tmp_path):
    """Issue 25's acceptance on the real FARO IRB 120 set (holdout 0.5, seed 0, and the swapped
    halves): held out at most 0.30 / 0.36 mm (DH,s,e: 0.447 / 0.532), measured over predicted
    in [0.67, 1.5]."""
    from fgcal.faro import convert_faro

    convert_faro(FARO, tmp_path / "faro")
    scores = {}
    for complement, limit in ((False, 0.30e-3), (True, 0.36e-3)):
        config = CalibrationConfig.defaults(
            tmp_path / "faro", formulation="tracker", model="DH,s,e,h", units={"length": "mm"},
            noise={"tracker_sigma": 0.05}, validation={"holdout": 0.5, "seed": 0, "complement": complement},
        )  # fmt: skip
        result = calibrate(config)
        held_out = result.validation["after"]["tool_point"].rms
        ratio = held_out / result.measured_prediction.rms
        scores[complement] = (held_out, ratio)
        assert held_out <= limit, scores
        assert 0.67 <= ratio <= 1.5, scores
        assert set(MOTION_NAMES) <= set(result.released)
    # The two halves are the two halves: fitted on one, held out on the other.
    assert scores[False][0] != scores[True][0]
