"""Compensation (issue 10, items 2 and 3): corrected commands from the calibrated model."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SEED_CELL, calibrate

import fgcal
from fgcal.calibration.config import CalibrationConfig
from fgcal.cli import main
from fgcal.compensate import compensate, nominal_of


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("compensate")
    simulate(SEED_CELL, out, seed=1, design="space_filling", n_configurations=300)
    return calibrate(CalibrationConfig.defaults(out))


def test_compensation_on_the_simulated_true_robot(calibrated):
    """200 random targets in the calibrated region: the compensated joints land within 1.5x the
    held-out RMS, at least 100x better than the nominal model's joints; every target reached
    in the model to 1e-9 m."""
    from fgcal.calibration.scoring import compensation_study

    study = compensation_study(calibrated, n_targets=200, seed=0)
    held_out = calibrated.validation["after"]["tool_point"].rms
    assert study.n_scored >= 190, study
    assert study.compensated_rms_m <= 1.5 * held_out, (study, held_out)
    assert study.uncompensated_rms_m >= 100 * study.compensated_rms_m, study
    assert study.model_residual_max_m < 1e-9


def test_unreachable_targets_are_flagged_not_fatal(calibrated):
    robot = calibrated.problem.robot
    nominal = nominal_of(robot, None)
    targets = np.array([[1.8, 0.2, 0.9], [25.0, 0.0, 0.0], [0.0, 0.0, -30.0]])
    result = compensate(robot, nominal, targets, None)
    assert result.status[0] == "ok" and list(result.status[1:]) == ["unreachable", "unreachable"]


def test_compensate_command_with_orientations_and_hints(calibrated, tmp_path, capsys):
    from fgcal.robot_io import save_robot
    from fgcal.se3 import so3_log

    robot_file = tmp_path / "calibrated_robot.yaml"
    robot = calibrated.problem.robot
    save_robot(robot_file, robot, robot.parameter_dict(calibrated.state.params))
    q = calibrated.problem.dataset.q[:5]
    T = fgcal.load_robot(robot_file).fk_tool(q)
    rows = ["target,x,y,z,rx,ry,rz," + ",".join(f"q{i}" for i in range(1, 7))]
    for i in range(5):
        rot = so3_log(T[i, :3, :3])
        values = [*T[i, :3, 3], *rot, *(q[i] + 0.01)]
        rows.append(",".join([f"p{i}", *(repr(float(v)) for v in values)]))
    (tmp_path / "targets.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    status = main(["compensate", str(robot_file), str(tmp_path / "targets.csv"), "--out", str(tmp_path / "o.csv")])
    assert status == 0, capsys.readouterr().err
    lines = (tmp_path / "o.csv").read_text().splitlines()
    assert lines[0].split(",")[-4:] == ["rz_cmd", "residual_m", "residual_rad", "status"]
    table = np.array([[float(v) for v in line.split(",")[1:-1]] for line in lines[1:]])
    np.testing.assert_allclose(table[:, :6], q, atol=1e-6)  # the calibrated joints of these poses
    assert all(line.endswith(",ok") for line in lines[1:])
    assert np.all(table[:, -2] < 1e-9) and np.all(table[:, -1] < 1e-9)


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("target,x,y\nt,1,2\n", "z"),
        ("target,x,y,z\nt,1,nan,2\n", "column y"),
        ("target,x,y,z,rx,ry\nt,1,2,3,0,0\n", "rx, ry and rz"),
        ("target,x,y,z,q1,q2\nt,1,2,3,0,0\n", "q1, q2, q3"),
        ("target,x,y,z\n", "no targets"),
        ("target,x,y,z\nt,1e300,0,0\n", "column x"),
    ],
    ids=["no_z", "nan", "partial_rotation", "partial_hints", "empty", "huge"],
)
def test_bad_targets_name_the_file_and_field(calibrated, tmp_path, capsys, text, field):
    (tmp_path / "t.csv").write_text(text, encoding="utf-8")
    status = main(["compensate", "kuka_kr125_2", str(tmp_path / "t.csv"), "--out", str(tmp_path / "o.csv")])
    error = capsys.readouterr().err.strip()
    assert status == 2 and error.startswith("fgcal: error: ") and "\n" not in error, error
    assert "t.csv" in error and field in error, error


def test_demo_calibrated_robot_exports_to_urdf(calibrated, tmp_path):
    """Issue 10 acceptance: the demo's calibrated robot, exported, read by yourdfpy: world ->
    tool0 equals fgcal's tool pose with the compliances at zero, to 1e-9 m and rad."""
    import yourdfpy

    from fgcal.robot_io import save_robot

    robot = calibrated.problem.robot
    save_robot(tmp_path / "calibrated_robot.yaml", robot, robot.parameter_dict(calibrated.state.params))
    assert main(["export", str(tmp_path / "calibrated_robot.yaml"), "--urdf", str(tmp_path / "cal.urdf")]) == 0
    loaded = fgcal.load_robot(tmp_path / "calibrated_robot.yaml")
    rigid = {name: 0.0 for name in loaded.parameter_names if name[:2] in ("kx", "ky", "kz")}
    assert any(loaded.nominal_parameters()[name] != 0.0 for name in rigid)  # compliances were estimated
    reference = yourdfpy.URDF.load(str(tmp_path / "cal.urdf"), load_meshes=False)
    rng = np.random.default_rng(5)
    for q in rng.uniform(loaded.limits[:, 0], loaded.limits[:, 1], (20, 6)):
        reference.update_cfg(q)
        assert np.abs(reference.get_transform("tool0", "world") - loaded.fk_tool(q, rigid)).max() < 1e-9
