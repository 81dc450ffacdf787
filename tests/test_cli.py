"""The fgcal command: user errors are one clear line with exit status 2, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fgcal.commands.cli import main


def test_simulate_missing_cell(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "none.yaml" in err and "file not found" in err


def test_simulate_malformed_cell(tmp_path, capsys):
    cell = tmp_path / "cell.yaml"
    cell.write_text("name: [unclosed\n")
    assert main(["simulate", str(cell), "--out", str(tmp_path / "o")]) == 2
    assert "malformed YAML" in capsys.readouterr().err


def test_fk_wrong_joint_count(capsys):
    assert main(["fk", "ur10e", "0", "0", "0"]) == 2
    assert "6 joints" in capsys.readouterr().err


def test_robots_lists_library(capsys):
    assert main(["robots"]) == 0
    assert "kuka_kr125_2" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--help"], ["simulate", "--help"]])
def test_console_entry_point(argv):
    command = [sys.executable, "-m", "fgcal", *argv]
    result = subprocess.run(command, capture_output=True, text=True, check=False)
    assert result.returncode == 0 and "usage" in result.stdout


def test_an_internal_error_is_a_traceback_and_exit_1_not_a_user_error(monkeypatch, capsys):
    """Issue 21: a bug (here a RuntimeError, as GTSAM raises, in a command) is never dressed as
    the user's: 'internal error', the traceback, exit status 1."""
    import fgcal.commands.listing

    def broken(_args):
        raise RuntimeError("Indeterminate linear system detected while working near variable p0")

    monkeypatch.setattr(fgcal.commands.listing, "cmd_robots", broken)
    assert main(["robots"]) == 1
    err = capsys.readouterr().err
    assert "internal error" in err and "Traceback" in err and "Indeterminate" in err


def test_fk_reads_degrees_only_when_told(capsys):
    """Issue 22, item 12: 90 without --deg is 90 rad: refused, naming the joint and --deg;
    the pose printed has no negative zeros."""
    assert main(["fk", "abb_irb120", "90", "0", "0", "0", "0", "0"]) == 2
    err = capsys.readouterr().err
    assert "q1" in err and "--deg" in err and "\n" not in err.strip()
    assert main(["fk", "abb_irb120", "90", "0", "0", "0", "0", "0", "--deg"]) == 0
    printed = capsys.readouterr().out
    assert "-0." not in printed and "ABB IRB 120" in printed


def test_a_local_folder_does_not_hide_a_bundled_cell(tmp_path, monkeypatch, capsys):
    """Issue 22, item 12: a folder named kr125_seed in the working directory does not hide the
    bundled cell; an unknown cell name lists the bundled cells."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "kr125_seed").mkdir()
    assert main(["simulate", "kr125_seed", "--out", "o", "--design", "space_filling", "--n", "5"]) == 0
    capsys.readouterr()
    assert main(["simulate", "no_such_cell", "--out", "o2"]) == 2
    err = capsys.readouterr().err
    assert "no_such_cell" in err and "kr125_seed" in err and "irb120_tracker" in err


def test_export_creates_its_folder(tmp_path, capsys):
    """Issue 22, item 12: fgcal export makes the folder it writes into."""
    assert main(["export", "abb_irb120", "--urdf", str(tmp_path / "new" / "dir" / "irb120.urdf")]) == 0
    assert (tmp_path / "new" / "dir" / "irb120.urdf").exists()
    assert (tmp_path / "new" / "dir" / "irb120.compliance.yaml").exists()
    assert main(["export", "abb_irb120", "--urdf", str(tmp_path / "new")]) == 2
