"""A config's settings that its formulation does not read are said in the headline (they were
silently ignored: fixture_orientation, pairs, a camera's noise and robust loss on a tracker
calibration), and the configs fgcal writes state none."""

from __future__ import annotations

import json

import pytest
from conftest import REPO

from fgcal.calibration.config import load_config
from fgcal.calibration.formulations import formulation as registered
from fgcal.commands.cli import main

CELLS = sorted(p.stem for p in (REPO / "datasets" / "cells").glob("*.yaml"))


@pytest.mark.parametrize("cell", CELLS)
def test_the_config_simulate_writes_states_only_what_its_formulation_reads(cell, tmp_path, capsys):
    sized = cell.startswith(("irb120_tracker", "dual_arm_tracker", "robot_positioner", "irb120_static",
                             "positioner_static", "humanoid"))
    size = ["--n", "12"] if sized else []
    assert main(["simulate", cell, "--out", str(tmp_path / "sim"), "--seed", "1", *size]) == 0
    capsys.readouterr()
    config = load_config(tmp_path / "sim" / "calibration.yaml")
    # One formulation, or several sets (each states what its own formulation reads).
    stated = [(s.formulation, s.stated_options) for s in config.sets] or [(config.formulation, config.stated_options)]
    for name, options in stated:
        formulation = registered(name)
        unread = options - set(formulation.settings_read) - {f"robust.{formulation.kind}"}
        assert not unread, (cell, name, sorted(unread))


def test_settings_another_formulation_reads_are_said(tmp_path, capsys):
    assert main(["simulate", "irb120_tracker", "--out", str(tmp_path / "sim"), "--n", "40", "--seed", "1"]) == 0
    (tmp_path / "c.yaml").write_text(
        "dataset: sim\nformulation: tracker\nfixture_orientation: estimate\npairs: {seed: 3}\n"
        "noise: {tracker_sigma: 1.5e-5, pixel_sigma_px: 0.2}\nrobust: {camera_points: null, tracker_points: none}\n"
    )
    assert main(["calibrate", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    warnings = json.loads((tmp_path / "out" / "report.json").read_text())["warnings"]
    said = [w for w in warnings if "does not read" in w]
    assert said and "fixture_orientation, noise.pixel_sigma_px, pairs, robust.camera_points;" in said[0], warnings
