"""What reaches the robot is what the calibration found (issue 43): the statuses of compensated
targets and programs (item 5), the payload and frames they use (items 2 and 3), and the
assumptions each controller-facing file states (item 4). The calibrations here are the bundled
robots with a few parameters moved (a calibration's result, without the solve)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

import fgcal
from fgcal.commands.cli import main
from fgcal.data.program_filter import WRITTEN, configurations
from fgcal.data.programs import format_krl_pose, format_rapid_pose, read_program
from fgcal.model.robot_io import save_robot


def _calibrated(folder: Path, name: str, moved: dict[str, float]) -> Path:
    """The bundled robot ``name`` with parameters moved by ``moved`` (added to their values)."""
    robot = fgcal.load_robot(name)
    values = robot.nominal_parameters()
    path = folder / f"{name}_calibrated.yaml"
    save_robot(path, robot, {key: float(values[key] + change) for key, change in moved.items()})
    return path


def _rows(path: Path) -> list[dict[str, str]]:
    """A CSV fgcal wrote, as its own reader reads it (comment lines first)."""
    from fgcal.data.dataset import read_csv

    header, body = read_csv(path, [])
    return [dict(zip(header, row, strict=True)) for row in body]


def _rapid(targets: list[tuple[str, np.ndarray, dict]], tool: str = "tool0", declarations: str = "") -> str:
    lines = ["MODULE M"]
    for name, T, c in targets:
        position, quaternion = format_rapid_pose(T)
        lines.append(f"  CONST robtarget {name}:=[{position},{quaternion},[{c['cf1']},{c['cf4']},{c['cf6']},"
                     f"{c['cfx']}],[9E9,9E9,9E9,9E9,9E9,9E9]];")  # fmt: skip
    lines += [declarations, "  PROC main()"] if declarations else ["  PROC main()"]
    lines += [f"    MoveJ {name}, v100, fine, {tool};" for name, _, _ in targets]
    return "\n".join([*lines, "  ENDPROC", "ENDMODULE", ""])


def _krl(targets: list[tuple[str, np.ndarray, dict]]) -> str:
    lines = ["DEFDAT P"]
    lines += [f"DECL E6POS {name}={{{format_krl_pose(T)},S {c['S']},T {c['T']}}}" for name, T, c in targets]
    return "\n".join([*lines, "ENDDAT", ""])


# -- item 5: statuses ------------------------------------------------------------------------------


def test_abbs_calibration_home_is_found(tmp_path, capsys):
    """ABB's calibration home (every joint 0, joint 5 too: joints 4 and 6 turn together) was
    "configuration not found": the controller's IK ended anywhere along that line, outside the
    quadrants cf4 and cf6 name. It is now corrected, on its own configuration."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {"a2": 2e-4, "theta3": 3e-4, "theta5": 2e-4})
    nominal = fgcal.load_robot("abb_irb120")
    q = np.zeros((1, 6))
    (tmp_path / "home.mod").write_text(_rapid([("home", nominal.fk(q)[0], configurations(nominal, "rapid", q)[0])]))
    assert main(["compensate", str(robot_file), str(tmp_path / "home.mod"), "--out", str(tmp_path / "o.mod")]) == 0
    (row,) = _rows(tmp_path / "o.corrections.csv")
    assert row["status"] in WRITTEN and row["corrected"] == "yes", row
    assert abs(float(row["q4_deg"]) + float(row["q6_deg"])) < 1.0, row  # on the branch of the home's quadrants
    capsys.readouterr()


def test_a_kuka_turn_changed_is_said(tmp_path, caplog):
    """A4 at +0.05 deg (T bit 3 clear), corrected to -0.15 deg: T is rewritten, and the target's
    status says so (it was "ok")."""
    robot_file = _calibrated(tmp_path, "kuka_kr125_2", {"theta4": np.radians(0.2), "a2": 3e-4})
    nominal = fgcal.load_robot("kuka_kr125_2")
    q = np.radians([[10, -80, 100, 0.05, 40, 20]])
    (tmp_path / "p.dat").write_text(_krl([("XP1", nominal.fk(q)[0], configurations(nominal, "krl", q)[0])]))
    assert main(["compensate", str(robot_file), str(tmp_path / "p.dat"), "--out", str(tmp_path / "o.dat")]) == 0
    (row,) = _rows(tmp_path / "o.corrections.csv")
    assert row["status"] == "turn changed" and row["corrected"] == "yes", row
    assert read_program(tmp_path / "o.dat").targets[0].config == {"S": 2, "T": 2 | 8}
    assert "new T (turn)" in caplog.text, caplog.text


def test_unreachable_rows_carry_no_commands(tmp_path, capsys):
    """An unreachable target's row has no joints and no command (they were the IK's last guess);
    --json's worst residual is of the compensated targets, the unreachable ones' gap apart."""
    (tmp_path / "t.csv").write_text("target,x,y,z\nnear,0.4,0.05,0.5\nfar,25,0,0\n")
    argv = ["compensate", "abb_irb120", str(tmp_path / "t.csv"), "--out", str(tmp_path / "o.csv"), "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    near, far = _rows(tmp_path / "o.csv")
    assert near["status"] == "ok" and all(near[c] for c in ("q1", "x_cmd", "z_cmd"))
    assert far["status"] == "unreachable" and float(far["residual_m"]) > 20
    assert all(far[c] == "" for c in ("q1", "q6", "x_cmd", "y_cmd", "z_cmd")), far
    assert out["residual_max_m"] < 1e-9 and out["unreachable_gap_max_m"] > 20, out
