"""No input is ever an output (issue 43, item 1): an output named as an input, or as a symbolic
or hard link to it, is refused before anything is written (exit 2, one line naming the file and
the option), and the input keeps its bytes. The check compares files (device and inode), not
names; it covers every file a command reads: ROBOT, TARGETS or PROGRAM, --nominal, --template,
--calibration and the URDF a robot file records."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from conftest import REPO

from fgcal.commands.cli import main
from fgcal.core.errors import InputError
from fgcal.core.outputs import distinct

ROBOTS = REPO / "datasets" / "robots"
RAPID = (
    "MODULE M\nCONST robtarget p1:=[[300,0,400],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
    "PROC main()\n  MoveL p1, v100, fine, tool0;\nENDPROC\nENDMODULE\n"
)
KRL = "DEFDAT P\nDECL E6POS XP1={X 1500,Y 0,Z 1500,A 0,B 90,C 0,S 2,T 2}\nENDDAT\n"


def _workspace(root: Path) -> None:
    """The inputs: a robot file recording its URDF, a UR nominal model, targets, programs, a config."""
    from fgcal.model.robot_io import load_robot, save_robot

    shutil.copy(ROBOTS / "seven_axis.urdf", root / "arm.urdf")
    save_robot(root / "cal.yaml", load_robot(root / "arm.urdf", tip="link_7"), {})
    shutil.copy(ROBOTS / "ur10e.yaml", root / "nom.yaml")
    (root / "targets.csv").write_text("target,x,y,z\nt,0.4,0,0.5\n")
    (root / "p.mod").write_text(RAPID)
    (root / "p.dat").write_text(KRL)
    (root / "calibration.yaml").write_text("dataset: data\n")


# (case id, the input the output is made to be, the command with {out} for the output)
CASES = [
    ("urdf_over_the_recorded_urdf", "arm.urdf", ["export", "cal.yaml", "--urdf", "{out}"], "--urdf"),
    ("urdf_over_the_template", "arm.urdf", ["export", "seven_axis", "--urdf", "{out}", "--tip", "link_7",
                                            "--template", "arm.urdf"], "--urdf"),
    ("ur_kinematics_over_the_nominal", "nom.yaml", ["export", "ur10e", "--ur-kinematics", "{out}", "--nominal",
                                                    "nom.yaml"], "--ur-kinematics"),
    ("ur_kinematics_over_the_robot", "nom.yaml", ["export", "nom.yaml", "--ur-kinematics", "{out}"],
     "--ur-kinematics"),
    ("ur_kinematics_over_the_calibration", "calibration.yaml", ["export", "ur10e", "--ur-kinematics", "{out}",
                                                                "--calibration", "calibration.yaml"],
     "--ur-kinematics"),
    ("commands_over_the_targets", "targets.csv", ["compensate", "abb_irb120", "targets.csv", "--out", "{out}"],
     "--out"),
    ("rapid_over_the_program", "p.mod", ["compensate", "abb_irb120", "p.mod", "--out", "{out}"], "--out"),
    ("krl_over_the_program", "p.dat", ["compensate", "kuka_kr125_2", "p.dat", "--out", "{out}"], "--out"),
]  # fmt: skip


def _same(root: Path, name: str) -> str:
    return name


def _symlink(root: Path, name: str) -> str:
    link = f"link_to_{Path(name).stem}{Path(name).suffix}"
    os.symlink(root / name, root / link)
    return link


def _hard_link(root: Path, name: str) -> str:
    link = f"hard_{Path(name).stem}{Path(name).suffix}"
    os.link(root / name, root / link)
    return link


KINDS: dict[str, Callable[[Path, str], str]] = {"path": _same, "symlink": _symlink, "hard_link": _hard_link}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(("name", "argv", "option"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_an_output_that_is_an_input_is_refused(tmp_path, monkeypatch, capsys, kind, name, argv, option):
    _workspace(tmp_path)
    monkeypatch.chdir(tmp_path)
    out = KINDS[kind](tmp_path, name)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    status = main([a.replace("{out}", out) for a in argv])
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert out in error and option in error, error
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before  # nothing written


def test_two_names_of_one_input_are_fine_and_a_new_output_is_fine(tmp_path):
    """Inputs may be one file (a robot its own nominal model); an output not written yet is no input."""
    (tmp_path / "robot.yaml").write_text("x")
    os.link(tmp_path / "robot.yaml", tmp_path / "same.yaml")
    distinct({"--out": tmp_path / "new.csv"}, {"ROBOT": tmp_path / "robot.yaml", "--nominal": tmp_path / "same.yaml"})
    with pytest.raises(InputError, match="same file"):  # two outputs of one name not yet written
        distinct({"--out": tmp_path / "new.csv", "the table": tmp_path / "." / "new.csv"}, {})


@pytest.mark.parametrize("link", ["path", "symlink", "hardlink"])
def test_calibrate_writes_no_report_over_what_it_reads(tmp_path, capsys, link):
    """Found by an engineer's trial: a dataset whose robot: is a calibrated_robot.yaml, calibrated
    with --out its own folder, had that robot file replaced by the new one (exit 0)."""
    from fgcal.simulation.simulate import simulate

    data = tmp_path / "data"
    simulate(REPO / "datasets" / "cells" / "irb120_tracker.yaml", data, seed=1, n_configurations=30)
    shutil.copy(ROBOTS / "abb_irb120.yaml", tmp_path / "robot.yaml")
    if link == "path":
        shutil.move(tmp_path / "robot.yaml", data / "calibrated_robot.yaml")
    elif link == "symlink":
        (data / "calibrated_robot.yaml").symlink_to(tmp_path / "robot.yaml")
    else:
        os.link(tmp_path / "robot.yaml", data / "calibrated_robot.yaml")
    header = (data / "dataset.yaml").read_text()
    (data / "dataset.yaml").write_text(header.replace("robot: abb_irb120", "robot: calibrated_robot.yaml"))
    (data / "c.yaml").write_text("dataset: .\nformulation: tracker\n")
    before = (data / "calibrated_robot.yaml").read_bytes()
    assert main(["calibrate", str(data / "c.yaml"), "--out", str(data), "--no-plots"]) == 2
    error = capsys.readouterr().err
    assert "calibrated_robot.yaml" in error and "--out" in error and "\n" not in error[:-1], error
    assert (data / "calibrated_robot.yaml").read_bytes() == before


@pytest.mark.parametrize("link", ["path", "symlink", "hardlink"])
@pytest.mark.parametrize(("what", "name"), [("configurations", "configurations.csv"), ("cell", "calibration.yaml"),
                                            ("robot", "dataset.yaml")])  # fmt: skip
def test_simulate_writes_over_none_of_its_inputs(tmp_path, capsys, link, what, name):
    """Found by a user trial: `fgcal simulate CELL --configurations plan/configurations.csv --out plan`
    replaced the plan's configurations.csv (its block column lost). The --configurations file, the
    cell and its robot file are refused as outputs, named as such or through a link, before anything
    is written."""
    plan, elsewhere = tmp_path / "plan", tmp_path / "inputs"
    plan.mkdir()
    elsewhere.mkdir()
    shutil.copy(ROBOTS / "kuka_kr125_2.yaml", elsewhere / "robot.yaml")
    cell_text = (REPO / "datasets" / "cells" / "kr125_seed.yaml").read_text()
    (elsewhere / "cell.yaml").write_text(cell_text.replace("robot: kuka_kr125_2", "robot: robot.yaml"))
    (elsewhere / "configurations.csv").write_text("config,q1,q2,q3,q4,q5,q6,block\np0000,0,-1.5,1.5,0,0.5,0,b1\n")
    source = {"configurations": "configurations.csv", "cell": "cell.yaml", "robot": "robot.yaml"}[what]
    if link == "path":
        shutil.move(elsewhere / source, plan / name)
        (elsewhere / source).symlink_to(plan / name)  # the input named through the output folder's file
    elif link == "symlink":
        (plan / name).symlink_to(elsewhere / source)
    else:
        os.link(elsewhere / source, plan / name)
    before = {p: p.read_bytes() for p in [*plan.iterdir(), *elsewhere.iterdir()]}
    argv = ["simulate", str(elsewhere / "cell.yaml"), "--configurations", str(elsewhere / "configurations.csv")]
    status = main([*argv, "--out", str(plan)])
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert name in error and "--out" in error and "same file" in error, error
    assert {p: p.read_bytes() for p in [*plan.iterdir(), *elsewhere.iterdir()]} == before
    assert sorted(p.name for p in plan.iterdir()) == [name]  # nothing written
