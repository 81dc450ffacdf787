"""The fgcal command: user errors are one clear line with exit status 2, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fgcal.cli import main


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
    result = subprocess.run([sys.executable, "-m", "fgcal.cli", *argv], capture_output=True, text=True, check=False)
    assert result.returncode == 0 and "usage" in result.stdout
