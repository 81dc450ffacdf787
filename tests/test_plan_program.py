"""fgcal plan --program: the plan as a program a controller runs (RAPID MoveAbsJ, KRL PTP to
E6AXIS, a CSV in degrees), read back by fgcal's own program reader to the same joints."""

from __future__ import annotations

import numpy as np
import pytest

from fgcal.commands.cli import main
from fgcal.core.errors import InputError
from fgcal.data.assumptions import Assumptions
from fgcal.data.dataset import read_csv
from fgcal.data.joint_programs import write_joint_program
from fgcal.data.programs import joint_path, read_program


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan")
    argv = ["plan", "irb120_tracker_lost_motion", "--n", "8", "--candidates", "200", "--out", str(out), "--approach",
            "unidirectional", "--approach-offset", "3", "--no-plots", "--program", "rapid", "krl", "csv-deg"]
    assert main(argv) == 0
    columns, rows = read_csv(out / "configurations.csv", [])
    table = np.array([[float(v) for v in row[1:]] for row in rows])
    q, before = np.degrees(table[:, :6]), np.degrees(table[:, 6:12])
    assert columns[7:13] == [f"before_q{i}" for i in range(1, 7)]
    # The path the robot drives: each approach point, then its configuration.
    return out, [row[0] for row in rows], np.stack([before, q], axis=1).reshape(-1, 6)


@pytest.mark.parametrize("program", ["cal_plan.mod", "cal_plan.dat"])
def test_the_program_drives_the_planned_joints(planned, program):
    out, names, path = planned
    read = joint_path(read_program(out / program))
    assert len(read) == len(path) == 2 * len(names)
    assert np.abs(np.array([t.joints_deg for t in read]) - path).max() < 1e-6
    if program.endswith(".mod"):
        expected = [name for n in names for name in (f"a_{n}", n)]
    else:  # KRL: E6AXIS XA_P0000, XP0000, moved to by the .src's PTPs
        expected = [name for n in names for name in (f"XA_{n.upper()}", f"X{n.upper()}")]
    assert [t.name for t in read] == expected


def test_the_programs_state_their_assumptions(planned):
    out, _, _ = planned
    for name, mark in (("cal_plan.mod", "!"), ("cal_plan.src", ";"), ("cal_plan.dat", ";"),
                       ("configurations_deg.csv", "#")):  # fmt: skip
        text = " ".join(line[1:].strip() for line in (out / name).read_text().splitlines() if line.startswith(mark))
        for word in ("frame:", "tool:", "payload:", "units:", "approach:", "kg", "deg", "3 deg below"):
            assert word in text, (name, word)
    columns, rows = read_csv(out / "configurations_deg.csv", [])
    assert columns[1] == "q1_deg" and columns[7] == "before_q1_deg" and len(rows) == 8


def test_a_rapid_or_krl_program_is_for_six_axes(tmp_path):
    words = Assumptions("what", "frame", "tool", "payload", "units", "approach")
    with pytest.raises(InputError, match="csv-deg"):
        write_joint_program("rapid", tmp_path, ["p0"], np.zeros((1, 7)), None, words, np.zeros(7, bool))
    (path,) = write_joint_program("csv-deg", tmp_path, ["p0"], np.full((1, 7), 0.1), None, words, np.zeros(7, bool))
    _, rows = read_csv(path, [])
    assert np.allclose([float(v) for v in rows[0][1:]], np.degrees(0.1))


QUICK = ["irb120_tracker_lost_motion", "--n", "8", "--candidates", "200", "--no-plots"]


def test_a_plan_into_a_dataset_folder_is_refused(tmp_path, capsys):
    """Found by a user trial: fgcal plan --out a dataset's folder replaced its configurations.csv,
    and the dataset no longer calibrated. Refused before planning, naming the dataset."""
    (tmp_path / "dataset.yaml").write_text("format: 1\n")
    (tmp_path / "configurations.csv").write_text("config,q1\nc1,0\n")
    assert main(["plan", *QUICK, "--out", str(tmp_path)]) == 2
    error = capsys.readouterr().err.strip()
    assert "dataset.yaml" in error and "--out" in error and "\n" not in error and "Traceback" not in error, error
    assert (tmp_path / "configurations.csv").read_text() == "config,q1\nc1,0\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["configurations.csv", "dataset.yaml"]


def test_a_new_plan_removes_the_earlier_plans_files_it_does_not_write(tmp_path, capsys):
    """Found by a user trial: re-planning into a plan's folder left the old plan's controller
    programs beside the new configurations.csv. fgcal plan's own files of the earlier plan that the
    new one does not write are removed, and the console says so; other files stay."""
    argv = ["plan", *QUICK, "--out", str(tmp_path)]
    assert main([*argv, "--approach", "unidirectional", "--program", "rapid", "krl", "csv-deg"]) == 0
    assert {"cal_plan.mod", "cal_plan.src", "cal_plan.dat", "configurations_deg.csv"} <= {
        p.name for p in tmp_path.iterdir()
    }
    (tmp_path / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main([*argv, "--approach", "unidirectional", "--seed", "2"]) == 0
    out = capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["configurations.csv", "notes.txt", "plan.json", "plan.md"]
    assert "removed the earlier plan's cal_plan.mod, cal_plan.src, cal_plan.dat, configurations_deg.csv" in out, out
    # A folder without a plan.json is not a plan's: nothing of it is removed.
    other = tmp_path / "other"
    other.mkdir()
    (other / "cal_plan.mod").write_text("MODULE X\nENDMODULE\n")
    assert main(["plan", *QUICK, "--out", str(other), "--approach", "unidirectional"]) == 0
    assert (other / "cal_plan.mod").read_text() == "MODULE X\nENDMODULE\n"


@pytest.mark.parametrize("approach", [[], ["--approach", "previous"]])
def test_an_approach_offset_without_approach_points_is_refused(tmp_path, capsys, approach):
    """Found by a user trial: --approach-offset 5 without --approach unidirectional was ignored
    (the plan reaches each configuration from the one before). Refused before planning."""
    argv = ["plan", *QUICK, "--out", str(tmp_path / "p"), "--approach-offset", "5", *approach]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert "--approach-offset" in error and "\n" not in error and "Traceback" not in error, error
    assert not (tmp_path / "p").exists()


def test_an_invalid_program_is_refused_before_planning(tmp_path, capsys):
    """Found by a user trial: --program rapid on a 7-axis cell planned, wrote configurations.csv,
    plan.json, plan.md and the figure, and only then exited 2. Refused before the work: nothing
    is written."""
    argv = ["plan", "seven_axis_touch", "--n", "30", "--out", str(tmp_path / "p"), "--program", "csv-deg", "rapid"]
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert "--program" in error and "7 joints" in error and "csv-deg" in error, error
    assert "\n" not in error and "Traceback" not in error, error
    assert not (tmp_path / "p").exists()


def test_the_programs_name_what_each_configuration_measures(tmp_path):
    """Each target's line says its pivot (block, point) as configurations.csv does (RAPID
    `! pivot p3`, KRL `; pivot p3`, a column of configurations_deg.csv), and fgcal's program
    reader still reads the same joints (to 1e-6 deg)."""
    argv = ["plan", "irb120_ballbar", "--n", "40", "--candidates", "200", "--no-plots", "--out", str(tmp_path),
            "--program", "rapid", "krl", "csv-deg"]  # fmt: skip
    assert main(argv) == 0
    header, rows = read_csv(tmp_path / "configurations.csv", ["config", "pivot"])
    pivots = {row[0]: row[header.index("pivot")] for row in rows}
    q = np.degrees(np.array([[float(v) for v in row[1:7]] for row in rows]))
    assert len(set(pivots.values())) > 1
    for program, mark, target in (("cal_plan.mod", "!", "CONST jointtarget {} "), ("cal_plan.dat", ";",
                                                                                    "DECL E6AXIS X{}=")):  # fmt: skip
        lines = (tmp_path / program).read_text().splitlines()
        for name, pivot in pivots.items():
            (line,) = [ln for ln in lines if target.format(name.upper() if mark == ";" else name) in ln]
            assert line.rstrip().endswith(f"{mark} pivot {pivot}"), line
        read = joint_path(read_program(tmp_path / program))
        assert np.abs(np.array([t.joints_deg for t in read]) - q).max() < 1e-6
    columns, deg = read_csv(tmp_path / "configurations_deg.csv", ["config", "pivot"])
    assert [row[columns.index("pivot")] for row in deg] == list(pivots.values())
    assert np.abs(np.array([[float(v) for v in row[1:7]] for row in deg]) - q).max() < 1e-6
