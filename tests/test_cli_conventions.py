"""The command line's conventions (issue 27): --version, -q and -v through logging, python -m
fgcal, fgcal list, --json (one strict JSON object, checked against a schema) and progress bars
only on a terminal."""

from __future__ import annotations

import json
import subprocess
import sys

import jsonschema
import numpy as np
import pytest
from conftest import REPO

from fgcal.commands.cli import main

NUMBER = {"type": "number"}
STATS = {"type": "object", "required": ["rms", "p95", "max"], "properties": {k: NUMBER for k in ("rms", "p95", "max")}}
PATHS = {"type": "object", "additionalProperties": {"type": "string"}}
SCHEMAS = {
    "simulate": {
        "required": ["command", "dataset", "calibration_config", "seed", "n_configurations", "observations",
                     "nominal_deviation_mean_m", "nominal_deviation_max_m"],
        "properties": {"seed": {"type": "integer"}, "n_configurations": {"type": "integer", "minimum": 1},
                       "observations": {"type": "object", "additionalProperties": {"type": "integer"}},
                       "nominal_deviation_mean_m": NUMBER, "nominal_deviation_max_m": NUMBER},
    },
    "calibrate": {
        "required": ["command", "out", "files", "model", "formulation", "headline"],
        "properties": {"files": PATHS, "headline": {"type": "object", "required": ["after_m", "before_m", "text"],
                                                     "properties": {"after_m": STATS, "text": {"type": "string"}}}},
    },
    "compensate": {
        "required": ["command", "out", "n_targets", "status", "residual_max_m"],
        "properties": {"status": {"type": "object", "additionalProperties": {"type": "integer"}},
                       "residual_max_m": NUMBER},
    },
    "plan": {
        "required": ["command", "out", "files", "predicted_sigma_m", "space_filling_sigma_m", "condition_number"],
        "properties": {"files": PATHS, "predicted_sigma_m": NUMBER, "condition_number": NUMBER},
    },
}  # fmt: skip


def _json_of(capsys, argv: list[str]) -> dict:
    assert main(argv) == 0
    out = capsys.readouterr().out
    document = json.loads(out, parse_constant=lambda name: pytest.fail(f"not strict JSON: {name}"))
    assert out.count("\n") == 1, "stdout holds the JSON object alone"
    return document


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("conventions")


def test_json_outputs_follow_their_schemas(work, capsys):
    """simulate, calibrate, compensate and plan with --json: one object, valid against its schema,
    the lines on stderr; the figures are the report's."""
    documents = {}
    documents["simulate"] = _json_of(capsys, ["simulate", "irb120_tracker", "--out", str(work / "sim"), "--n", "30",
                                              "--json"])  # fmt: skip
    documents["calibrate"] = _json_of(
        capsys,
        ["calibrate", str(work / "sim" / "calibration.yaml"), "--out", str(work / "cal"), "--no-plots", "--json"],
    )
    report = json.loads((work / "cal" / "report.json").read_text())
    assert documents["calibrate"]["headline"] == report["headline"]
    import fgcal

    robot = fgcal.load_robot(work / "cal" / "calibrated_robot.yaml")
    positions = robot.fk_tool(np.array([[0, 0.3, -0.3, 0, 0.5, 0], [0.2, 0.3, -0.3, 0, 0.5, 0]]))[:, :3, 3]
    (work / "t.csv").write_text("target,x,y,z\n" + "".join(f"t{i},{x},{y},{z}\n" for i, (x, y, z) in
                                                          enumerate(positions)))  # fmt: skip
    documents["compensate"] = _json_of(
        capsys, ["compensate", str(work / "cal" / "calibrated_robot.yaml"), str(work / "t.csv"), "--out",
                 str(work / "c.csv"), "--json"]
    )  # fmt: skip
    documents["plan"] = _json_of(capsys, ["plan", "irb120_tracker", "--n", "8", "--candidates", "100", "--out",
                                          str(work / "plan"), "--no-plots", "--json"])  # fmt: skip
    for command, document in documents.items():
        assert document["command"] == command
        jsonschema.validate(document, {"type": "object", **SCHEMAS[command]})
    assert documents["compensate"]["status"] == {"ok": 2}


def test_version_and_python_dash_m():
    from importlib.metadata import version

    for argv in ([sys.executable, "-m", "fgcal", "--version"], [sys.executable, "-m", "fgcal", "list", "cells"]):
        done = subprocess.run(argv, capture_output=True, text=True, cwd=REPO.parent, check=False, timeout=120)
        assert done.returncode == 0, done.stderr
    assert (
        f"fgcal {version('fgcal')}"
        in subprocess.run(
            [sys.executable, "-m", "fgcal", "--version"], capture_output=True, text=True, check=True, timeout=120
        ).stdout
    )


def test_list_robots_and_cells(capsys):
    assert main(["list", "robots"]) == 0
    robots = capsys.readouterr().out
    assert "kuka_kr125_2" in robots and "seven_axis" in robots
    assert main(["list", "cells"]) == 0
    cells = capsys.readouterr().out.splitlines()
    assert len(cells) == len(list((REPO / "datasets" / "cells").glob("*.yaml")))
    assert any(line.startswith("kr125_seed ") and "KUKA KR 125/2" in line for line in cells)
    assert main(["list", "boats"]) == 2


def test_quiet_and_verbose(work, capsys):
    config = str(work / "sim" / "calibration.yaml")
    if not (work / "sim").exists():
        assert main(["simulate", "irb120_tracker", "--out", str(work / "sim"), "--n", "30"]) == 0
    capsys.readouterr()
    assert main(["calibrate", config, "--out", str(work / "q"), "--no-plots", "-q"]) == 0
    assert capsys.readouterr().out == ""
    assert main(["-q", "calibrate", config, "--out", str(work / "q2"), "--no-plots"]) == 0  # -q before the command
    assert capsys.readouterr().out == ""
    assert main(["-q", "list", "robots"]) == 0  # a listing is the command's result, not a log line
    assert "abb_irb120" in capsys.readouterr().out
    assert main(["calibrate", config, "--out", str(work / "v"), "--no-plots"]) == 0
    normal = capsys.readouterr().out
    assert main(["calibrate", config, "--out", str(work / "v"), "--no-plots", "-v"]) == 0
    verbose = capsys.readouterr().out
    assert "sigma" in verbose and "from nominal" in verbose and "from nominal" not in normal
    assert len(verbose.splitlines()) > len(normal.splitlines())


def test_progress_bar_only_on_a_terminal(monkeypatch, capsys):
    """The bar draws on a terminal and not elsewhere; the lines go to the log either way."""
    import io

    from fgcal.core import console

    console.setup()
    reporter = console.Reporter()
    reporter.step("phase", 1, 4)
    reporter("a line")
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == "a line\n"  # not a terminal: no bar

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    for done in range(1, 5):
        reporter.step("phase", done, 4)
    assert "phase" in terminal.getvalue() and "4/4" in terminal.getvalue()
    assert not console._BARS  # closed when done
