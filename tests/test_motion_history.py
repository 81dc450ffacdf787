"""Issue 25: the robot's motion history in the model (fgcal.model.motion): lost motion and a speed
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
from fgcal.core.errors import InputError
from fgcal.data.dataset import load_dataset
from fgcal.data.truth import load_truth
from fgcal.model.motion import LOST_MOTION_WIDTH_RAD, MotionHistory, features
from fgcal.reports.calibration import write_report
from fgcal.simulation.simulate import simulate

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


def test_the_residual_model_is_not_used_where_nothing_is_left(lost_motion_cell):
    """On the simulated cell, the model leaves only the tracker's noise: the Gaussian process
    does not win its cross-validation, and says so."""
    config = CalibrationConfig.defaults(lost_motion_cell, formulation="tracker", model="DH,s,e,h", residual_model="gp")
    result = calibrate(config)
    assert not result.residual_model.used, result.residual_model
    assert result.residual_model.cv_rms_with_m > 0.98 * result.residual_model.cv_rms_without_m


def test_the_residual_model_needs_point_errors(lost_motion_cell, tmp_path):
    from fgcal.calibration.residual_model import fit_residual_model

    data = tmp_path / "pairs"
    simulate(DATASETS / "cells" / "kr125_seed.yaml", data, seed=1)  # its seed design's 36 viewpoints
    result = calibrate(CalibrationConfig.defaults(data, formulation="projection", validation={"holdout": 0.0}))
    with pytest.raises(InputError, match="residual_model"):
        fit_residual_model(result.problem, result.state, None)


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
@pytest.mark.parametrize(
    "complement, limit, with_gp",
    [(False, 0.30e-3, 0.24e-3), pytest.param(True, 0.36e-3, 0.29e-3, marks=pytest.mark.study)],
    ids=["half_a", "half_b"],
)
def test_real_faro_set_with_the_motion_terms_on_both_halves(complement, limit, with_gp, tmp_path):
    """Issue 25's acceptance on the real FARO IRB 120 set (holdout 0.5, seed 0, and the swapped
    halves): held out at most 0.30 / 0.36 mm (DH,s,e: 0.447 / 0.532), measured over predicted
    in [0.67, 1.5]; with the residual model at most 0.24 / 0.29 mm, predicted as well. The
    swapped half (18 s) runs with the studies (pytest -m study): the suite keeps under 6 minutes."""
    from fgcal.data.faro import convert_faro

    convert_faro(FARO, tmp_path / "faro")
    config = CalibrationConfig.defaults(
        tmp_path / "faro", formulation="tracker", model="DH,s,e,h", units={"length": "mm"},
        noise={"tracker_sigma": 0.05}, validation={"holdout": 0.5, "seed": 0, "complement": complement},
        residual_model="gp",
    )  # fmt: skip
    result = calibrate(config)
    held_out = result.validation["after"]["tool_point"].rms
    ratio = held_out / result.measured_prediction.rms
    assert held_out <= limit, (held_out, ratio)
    assert 0.67 <= ratio <= 1.5, (held_out, ratio)
    assert set(MOTION_NAMES) <= set(result.released)
    gp = result.residual_model
    assert gp.used and gp.held_out_rms_without_m == held_out
    assert gp.held_out_rms_m <= with_gp, gp
    assert 0.67 <= gp.held_out_rms_m / gp.predicted_rms_m <= 1.5, gp


def test_compensate_command_allows_for_the_approach(calibrated, tmp_path, capsys):
    from fgcal.commands.cli import main
    from fgcal.model.robot_io import load_robot

    write_report(calibrated, tmp_path / "report", plots=False)
    robot_file = tmp_path / "report" / "calibrated_robot.yaml"
    robot = load_robot(robot_file)
    assert robot.model == "DH,s,e,h"
    q = calibrated.problem.dataset.q[:6]
    positions = robot.fk(q)[:, :3, 3]
    targets = tmp_path / "targets.csv"
    before = ["", "", "", "0.1,0.2,0.3,0.4,0.5,0.6", "", ""]
    rows = [f"t{k},{p[0]},{p[1]},{p[2]},{b or ',,,,,'}" for k, (p, b) in enumerate(zip(positions, before, strict=True))]
    header = "target,x,y,z," + ",".join(f"before_q{i}" for i in range(1, 7))
    targets.write_text("\n".join([header, *rows]) + "\n")
    assert main(["compensate", str(robot_file), str(targets), "--out", str(tmp_path / "with.csv")]) == 0
    assert "approached from the previous one" in capsys.readouterr().out
    assert main(["compensate", str(robot_file), str(targets), "--out", str(tmp_path / "without.csv"),
                 "--approach", "none"]) == 0  # fmt: skip
    # (the lines after the # lines that state the commands' assumptions)
    with_lines = [line for line in (tmp_path / "with.csv").read_text().splitlines() if line[0] != "#"]
    without_lines = [line for line in (tmp_path / "without.csv").read_text().splitlines() if line[0] != "#"]
    assert "# approach: lost motion allowed for" in (tmp_path / "with.csv").read_text()
    assert "lost_motion_q1" in with_lines[0] and "lost_motion" not in without_lines[0]
    allowed = np.array([[float(v) for v in line.split(",")[1:7]] for line in with_lines[1:]])
    plain = np.array([[float(v) for v in line.split(",")[1:7]] for line in without_lines[1:]])
    columns = with_lines[0].split(",")
    lost = np.array([[float(v) for v in line.split(",")[columns.index("lost_motion_q1"):][:6]]
                     for line in with_lines[1:]])  # fmt: skip
    # The first target's approach is unknown: no allowance; the others differ by exactly it.
    assert np.all(lost[0] == 0.0) and np.all(np.abs(lost[1:]).max(axis=1) > 1e-5)
    np.testing.assert_allclose(allowed, plain - lost, atol=1e-12)
    # Row 4 is approached from the joints given: its allowance follows from them.
    direct = features(allowed[3:4], MotionHistory(np.array([[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]]), np.ones(1)))
    params = robot.parameter_dict(robot.parameter_vector())
    lm = np.array([params[f"lm{i}"] for i in range(1, 7)])
    lv = np.array([params[f"lv{i}"] for i in range(1, 7)])
    np.testing.assert_allclose(lost[3], direct[0, :6] * lm + direct[0, 6:] * lv, atol=1e-12)
    # A URDF holds none of it: the sidecar carries the terms.
    import yaml

    assert main(["export", str(robot_file), "--urdf", str(tmp_path / "arm.urdf")]) == 0
    sidecar = yaml.safe_load((tmp_path / "arm.compliance.yaml").read_text())
    assert "motion_history" in sidecar
    np.testing.assert_allclose([j["lost_motion"] for j in sidecar["joints"]], lm, rtol=1e-12)
    np.testing.assert_allclose([j["speed_term"] for j in sidecar["joints"]], lv, rtol=1e-12)


def test_a_rapid_program_is_corrected_along_its_moves(calibrated, tmp_path, capsys):
    """The targets are declared p0..p7 but moved to in reverse: each corrected target allows for
    the lost motion of its approach from the one moved to before it (corrections.csv); p2 is
    reached from an Offs point, which is no target: it gets no allowance."""
    from test_program_filter import RAPID, _quaternion

    from fgcal.commands.cli import main
    from fgcal.core.se3 import pose_from_xyz_rpy
    from fgcal.data.compensation import nominal_of
    from fgcal.data.program_filter import configurations

    write_report(calibrated, tmp_path / "report", plots=False)
    robot_file = tmp_path / "report" / "calibrated_robot.yaml"
    nominal = nominal_of(calibrated.problem.robot, None)
    middle, half = nominal.limits.mean(axis=1), np.diff(nominal.limits, axis=1)[:, 0] / 2
    q = middle + 0.4 * half * np.random.default_rng(5).uniform(-1, 1, (8, 6))
    q[:, 4] = np.sign(q[:, 4]) * np.maximum(np.abs(q[:, 4]), 0.3)  # away from the wrist singularity
    tcp = pose_from_xyz_rpy([0, 0, 0.1], [0, 0, 0])
    taught = nominal.fk(q) @ tcp
    lines, moves = [], []
    for k, (T, c) in enumerate(zip(taught, configurations(nominal, "rapid", q), strict=True)):
        quaternion = _quaternion(T[:3, :3])
        lines.append(
            f"    CONST robtarget p{k}:=[[{T[0, 3] * 1e3:.4f},{T[1, 3] * 1e3:.4f},{T[2, 3] * 1e3:.4f}],"
            f"[{','.join(f'{v:.10f}' for v in quaternion)}],[{c['cf1']},{c['cf4']},{c['cf6']},{c['cfx']}],"
            "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];"
        )
    moves = [f"        MoveL p{k}, v100, fine, torch\\WObj:=table;" for k in reversed(range(len(q)))]
    moves.insert(5, "        MoveJ Offs(p2, 0, 0, 50), v100, z10, torch\\WObj:=table;")
    identity = "1,0,0,0"
    text = RAPID.format(n=len(q), tz=100, tq=identity, wx=0, wy=0, wz=0, wq=identity,
                        targets="\n".join(lines), moves="\n".join(moves))  # fmt: skip
    (tmp_path / "cell.mod").write_text(text)
    out = tmp_path / "cell_cal.mod"
    assert main(["compensate", str(robot_file), str(tmp_path / "cell.mod"), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "the module's motion instruction before its first use" in said
    assert "2 (p2, p7) come from an Offs/RelTool point or nothing: no allowance" in said, said
    table = [line for line in (tmp_path / "cell_cal.corrections.csv").read_text().splitlines() if line[0] != "#"]
    header = table[0].split(",")
    rows = [line.split(",") for line in table[1:]]
    assert all(row[header.index("status")] == "ok" for row in rows)
    joints = np.radians([[float(row[header.index(f"q{i}_deg")]) for i in range(1, 7)] for row in rows])
    lost = np.radians([[float(row[header.index(f"lost_motion_q{i}_mdeg")]) for i in range(1, 7)] for row in rows])
    lost /= 1e3
    path = np.arange(len(q))[::-1]
    before = np.vstack([np.full((1, 6), np.nan), joints[path][:-1]])
    before[path == 2] = np.nan  # after the Offs point
    expected = features(joints[path], MotionHistory(before, np.ones(len(path))))
    params = calibrated.problem.robot.parameter_dict(calibrated.state.params)
    lm = np.array([params[f"lm{i}"] for i in range(1, 7)])
    lv = np.array([params[f"lv{i}"] for i in range(1, 7)])
    offsets = expected[:, :6] * lm + expected[:, 6:] * lv
    # p7 is moved to first: its approach is unknown; the others follow the moves, not the names.
    assert np.all(lost[7] == 0.0) and np.all(lost[2] == 0.0)
    # The table's joints are rounded to 1e-4 deg, which moves the lost motion's tanh by up to
    # lm * 5e-5 deg / 1 deg: 1e-5 deg is that bound with margin; the offsets are 1e-2 deg.
    np.testing.assert_allclose(lost[path], offsets, atol=np.radians(1e-5))
    assert np.abs(lost[:7]).max() > np.radians(0.01)


def test_a_unidirectional_plan_predicts_what_it_gains(tmp_path):
    """fgcal plan --approach unidirectional: approach points 2 deg below every configuration; the
    plan predicts the lost motion a static model cannot absorb, in order and approached from
    below, and simulations of both plans calibrated with DH,s,e show it."""
    from fgcal.planning.plan import plan, write_plan

    held_out = {}
    for approach in ("previous", "unidirectional"):
        result = plan(LOST_MOTION_CELL, 60, n_candidates=1000, approach=approach)
        write_plan(result, tmp_path / approach, plot=False)
        lost = result.lost_motion
        assert lost["unidirectional_rms_m"] == 0.0 and lost["in_order_rms_m"] > 0.3e-3
        header = (tmp_path / approach / "configurations.csv").read_text().splitlines()[0]
        assert ("before_q1" in header) == (approach == "unidirectional")
        simulate(LOST_MOTION_CELL, tmp_path / f"sim_{approach}", seed=3,
                 configurations=tmp_path / approach / "configurations.csv")  # fmt: skip
        dataset = load_dataset(tmp_path / f"sim_{approach}")
        if approach == "unidirectional":
            np.testing.assert_allclose(dataset.q - dataset.motion_history.before, np.radians(2.0), atol=1e-12)
        calibrated = score_with_truth(calibrate(CalibrationConfig.defaults(tmp_path / f"sim_{approach}",
                                                                           formulation="tracker")))  # fmt: skip
        held_out[approach] = (calibrated.validation["after"]["tool_point"].rms, calibrated.prediction.rms, lost)
    # Approached from below, the static model holds out what its own prediction says.
    rms, predicted, _ = held_out["unidirectional"]
    assert 1 / 1.5 <= rms / predicted <= 1.5, held_out
    # In order, it is left with the lost motion the plan predicted.
    rms, _, lost = held_out["previous"]
    assert 1 / 1.5 <= rms / lost["in_order_rms_m"] <= 1.5, held_out
    assert rms > 20 * held_out["unidirectional"][0]


def test_an_ordered_split_holds_out_the_end_of_the_run(lost_motion_cell):
    from fgcal.calibration.run import build_problem

    dataset = load_dataset(lost_motion_cell)
    for complement in (False, True):
        validation = {"holdout": 0.25, "split": "ordered", "complement": complement}
        config = CalibrationConfig.defaults(lost_motion_cell, formulation="tracker", validation=validation)
        problem = build_problem(dataset, config)
        first, last = np.arange(150), np.arange(150, 200)
        fit, test = (last, first) if complement else (first, last)
        np.testing.assert_array_equal(problem.fit, fit)
        np.testing.assert_array_equal(problem.test, test)


def test_close_and_repeated_targets_are_compensated_or_said(calibrated, tmp_path):
    """Targets 0.2 deg apart and one repeated: every solved command, driven through the
    calibrated model with the history the commands themselves make, lands on its target; a
    target whose allowance cannot be solved (the speed term of a tiny move) is flagged, not a
    failure of the whole file."""
    import fgcal

    write_report(calibrated, tmp_path / "report", plots=False)
    robot = fgcal.load_robot(tmp_path / "report" / "calibrated_robot.yaml")
    q0 = calibrated.problem.dataset.q[20]
    q = np.array([q0 + k * np.radians(0.2) for k in range(6)] + [q0 + 5 * np.radians(0.2)])
    targets = robot.fk_tool(q)[:, :3, 3]
    result = fgcal.compensate(robot, targets, hints=q)
    assert result.motion_solved is not None and result.motion_solved[1:6].all()
    landed = robot.fk_tool(result.q, motion=features(result.q, MotionHistory.in_order(result.q)))[:, :3, 3]
    solved = result.motion_solved
    assert np.abs(landed - targets)[solved].max() < 1e-9
    # Without the allowance the same commands miss by the lost motion.
    plain = fgcal.compensate(robot, targets, hints=q, approach="none")
    missed = robot.fk_tool(plain.q, motion=features(plain.q, MotionHistory.in_order(plain.q)))[:, :3, 3]
    assert np.abs(missed - targets)[1:6].max() > 1e-5


def test_the_truth_keeps_the_simulated_history(lost_motion_cell, tmp_path):
    """A dataset whose order is then declared unknown is scored against the true robot as the
    simulator moved it; and the motion history's model refuses a dataset without a history."""
    import shutil

    data = tmp_path / "data"
    shutil.copytree(lost_motion_cell, data)
    config = CalibrationConfig.defaults(data, formulation="tracker")
    first = score_with_truth(calibrate(config)).validation["before"]["tool_point"].rms
    (data / "dataset.yaml").write_text((data / "dataset.yaml").read_text() + "order: unknown\n")
    assert not load_dataset(data).motion_history.known().any()
    again = score_with_truth(calibrate(config)).validation["before"]["tool_point"].rms
    assert again == pytest.approx(first, rel=1e-12)
    with pytest.raises(InputError, match="gives none"):
        calibrate(CalibrationConfig.defaults(data, formulation="tracker", model="DH,s,e,h"))
    # model: auto then compares the models that need no history.
    small = tmp_path / "small"
    simulate(DATASETS / "cells" / "irb120_tracker.yaml", small, seed=1, n_configurations=30)
    (small / "dataset.yaml").write_text((small / "dataset.yaml").read_text() + "order: unknown\n")
    result = calibrate(CalibrationConfig.defaults(small, formulation="tracker", model="auto"))
    assert {row.model for row in result.model_comparison} == {"DH", "DH,s", "DH,s,e"}


def test_without_scikit_learn_the_residual_model_is_refused_before_calibrating(lost_motion_cell, monkeypatch):
    import importlib.util

    from fgcal.calibration.run import build_problem

    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "sklearn" else found(name, *a))
    config = CalibrationConfig.defaults(lost_motion_cell, formulation="tracker", residual_model="gp")
    with pytest.raises(InputError, match=r"residual_model: needs scikit-learn: pip install '\.\[residual\]'"):
        build_problem(load_dataset(lost_motion_cell), config)
