"""Issue 42, item 4: every formulation plannable through the protocol. The static camera
(a camera fixed in the cell watching a board on the flange) is planned: candidates where the
nominal camera sees the whole board, six compressed rows per candidate carrying the
information of all the board's corners; its plan simulates exactly."""

from __future__ import annotations

import json

import numpy as np
from conftest import SEED_CELL

from fgcal.calibration.plan_model import StaticBoard, _board_rows
from fgcal.commands.cli import main
from fgcal.core.se3 import inverse, so3_exp, transform_points
from fgcal.data.dataset import load_dataset
from fgcal.model import kinematics
from fgcal.simulation.cell import load_cell
from fgcal.simulation.static_camera import board_in_camera, board_seen

STATIC = SEED_CELL.parent / "irb120_static_camera.yaml"


def _pose(xi: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = so3_exp(xi[:3]), xi[3:]
    return T


def test_static_board_rows_carry_every_corner():
    """The six rows' information equals that of every corner's pixels (pinhole), by central
    differences on the parameters, the camera's pose and the board's mounting."""
    cell = load_cell(STATIC)
    robot = cell.robot.with_model("DH,s,e")
    cand = StaticBoard().candidates(cell, 3, np.random.default_rng(0))
    names = ["a2", "theta3", "d4", "alpha2", "theta5", "kx2"]
    params = robot.parameter_vector()
    J_p, J_aux = _board_rows(robot, kinematics.forward(robot, params, cand.q), cell, names)
    setup = cell.static_camera

    identity = np.eye(4)

    def pixels(vector, camera=identity, board=identity):
        T_W_n = kinematics.frame_pose(robot, kinematics.forward(robot, vector, cand.q), cell.tip)
        p = transform_points((camera @ inverse(setup.pose) @ T_W_n @ board @ setup.board_mount)[:, None],
                             setup.board_points)  # fmt: skip
        return np.stack([setup.camera.fx * p[..., 0] / p[..., 2], setup.camera.fy * p[..., 1] / p[..., 2]], -1)

    h, columns = 1e-7, []
    for name in names:
        step = robot.parameter_vector({name: robot.nominal_parameters()[name] + h}) - params
        columns.append((pixels(params + step) - pixels(params - step)) / (2 * h))
    for which in ("camera", "board"):
        for k in range(6):
            xi = np.zeros(6)
            xi[k] = h
            columns.append((pixels(params, **{which: _pose(xi)}) - pixels(params, **{which: _pose(-xi)})) / (2 * h))
    F = np.stack(columns, -1).reshape(len(cand.q), -1, len(columns))
    J = np.concatenate([J_p, J_aux], axis=2)
    for f, j in zip(F, J, strict=True):
        np.testing.assert_allclose(j.T @ j, f.T @ f, rtol=1e-6, atol=1e-6 * np.abs(f.T @ f).max())


def test_static_camera_plans_and_simulates(tmp_path):
    out = tmp_path / "plan"
    argv = ["plan", "irb120_static_camera", "--n", "12", "--candidates", "300", "--out", str(out), "--no-plots"]
    assert main(argv) == 0
    plan = json.loads((out / "plan.json").read_text())
    assert plan["formulation"] == "static_camera" and plan["measurement_sigma"]["unit"] == "px"
    assert "static_camera.tx" in plan["auxiliary_unknowns"] and plan["discarded"]
    assert plan["predicted_position_sigma_rms_m"] < plan["space_filling_same_n_sigma_rms_m"]
    q = np.loadtxt(out / "configurations.csv", delimiter=",", skiprows=1, usecols=range(1, 7))
    cell = load_cell(STATIC)
    assert board_seen(cell, board_in_camera(cell, q, {})).all()  # the nominal camera sees every board
    sim = tmp_path / "sim"
    assert main(["simulate", "irb120_static_camera", "--configurations", str(out / "configurations.csv"),
                 "--out", str(sim), "-q"]) == 0  # fmt: skip
    dataset = load_dataset(sim)
    assert "pixels" in dataset.tables and 10 <= len(dataset.q) <= 12


def test_touch_plans_simulates_and_calibrates(tmp_path):
    """A touch cell is planned: each candidate seats the probe in a point from above on the
    nominal model, the plan names each configuration's point, the known distances are
    information every design has, and the plan simulates exactly (the true robot seated with
    the plan's orientation) and calibrates."""
    from fgcal.calibration.config import CalibrationConfig
    from fgcal.calibration.run import calibrate

    out = tmp_path / "plan"
    argv = ["plan", "seven_axis_touch", "--n", "60", "--candidates", "400", "--out", str(out), "--no-plots"]
    assert main(argv) == 0
    plan = json.loads((out / "plan.json").read_text())
    assert plan["formulation"] == "touch" and "probe.x" in plan["auxiliary_unknowns"]
    assert plan["predicted_position_sigma_rms_m"] < plan["space_filling_same_n_sigma_rms_m"]
    lines = (out / "configurations.csv").read_text().splitlines()
    assert lines[0].endswith(",q7,point")
    points = [line.rsplit(",", 1)[1] for line in lines[1:]]
    # The greedy start alone touched one point only (a first touch tells nothing about the
    # robot): the exchange from the space-filling design touches several, each more than once.
    touched = {p: points.count(p) for p in set(points)}
    assert len(touched) >= 3 and min(touched.values()) >= 2, touched
    sim = tmp_path / "sim"
    assert main(["simulate", "seven_axis_touch", "--configurations", str(out / "configurations.csv"),
                 "--out", str(sim), "-q"]) == 0  # fmt: skip
    dataset = load_dataset(sim)
    assert len(dataset.q) >= 55
    config = CalibrationConfig.defaults(sim, formulation="touch", validation={"holdout": 0.0}, compliant_joints=[2, 4])
    result = calibrate(config)  # the cell's compliant joints, as simulate's calibration.yaml suggests
    assert result.fit.chi2_per_dof < 2.0


def test_ballbar_plans_simulates_and_calibrates(tmp_path):
    """A ballbar cell is planned: readings with the ball within the bar's travel of a pivot,
    the flange down within max_tilt, on the nominal model; each pivot read at least six times;
    the plan names each reading's pivot, simulates exactly (the true distance at the plan's
    joints) and calibrates."""
    from fgcal.calibration.config import CalibrationConfig
    from fgcal.calibration.run import calibrate

    out = tmp_path / "plan"
    argv = ["plan", "irb120_ballbar", "--n", "150", "--candidates", "400", "--out", str(out), "--no-plots"]
    assert main(argv) == 0
    plan = json.loads((out / "plan.json").read_text())
    assert plan["formulation"] == "distances" and "ball.x" in plan["auxiliary_unknowns"]
    assert plan["predicted_position_sigma_rms_m"] < plan["space_filling_same_n_sigma_rms_m"]
    lines = (out / "configurations.csv").read_text().splitlines()
    assert lines[0].endswith(",q6,pivot")
    pivots = [line.rsplit(",", 1)[1] for line in lines[1:]]
    assert min(pivots.count(p) for p in set(pivots)) >= 6
    sim = tmp_path / "sim"
    assert main(["simulate", "irb120_ballbar", "--configurations", str(out / "configurations.csv"),
                 "--out", str(sim), "-q"]) == 0  # fmt: skip
    dataset = load_dataset(sim)
    assert len(dataset.q) >= 140
    result = calibrate(CalibrationConfig.defaults(sim, formulation="distances", validation={"holdout": 0.0}))
    assert result.fit.chi2_per_dof < 2.0
