"""The report's verdict at a glance (issue 27): a headline with the held-out accuracy after and
before, orientation where 6D poses are measured, the worst configurations and ISO 9283 figures,
through the top-level Python API."""

from __future__ import annotations

import numpy as np
from conftest import REPO

import fgcal
from fgcal.simulation.simulate import simulate


def test_a_6d_calibration_headline_states_the_orientation(tmp_path):
    simulate(REPO / "datasets" / "cells" / "irb120_tracker6d.yaml", tmp_path / "data", seed=3, n_configurations=60)
    calibration = fgcal.calibrate(tmp_path / "data", formulation="poses")
    h = calibration.headline
    measured = calibration.result.measured["after"]
    orientation = next(v for k, v in measured.items() if k.endswith("_rad"))
    assert h["orientation_after_rad"]["rms"] == orientation.rms
    assert f"{orientation.rms * 180e3 / np.pi:#.4g}".rstrip(".") + " mdeg RMS" in h["text"]
    assert h["after_m"]["rms"] == calibration.result.validation["after"]["tool_point"].rms
    assert h["after_m"]["rms"] < h["before_m"]["rms"] and h["reference"] == "ground truth"
    assert calibration.held_out == {"after_m": h["after_m"], "before_m": h["before_m"]}
    # Named estimates and sigmas; a one-line repr.
    assert set(calibration.sigmas) == set(calibration.estimates) == set(calibration.result.released)
    assert "\n" not in repr(calibration) and "poses formulation" in repr(calibration)
    assert repr(calibration.robot).startswith("<Robot 'ABB IRB 120': 6 revolute joints")
    doc = calibration.write_report(tmp_path / "report", plots=False)
    worst = doc["worst_configurations"]
    errors = [row["error_m"] for row in worst]
    assert (
        errors == sorted(errors, reverse=True) and errors[0] == calibration.result.validation["after"]["tool_point"].max
    )
    assert doc["iso9283"]["poses"] == len(calibration.result.problem.test)
    assert doc["iso9283"]["ap_max_m"] <= errors[0] + 1e-15


def test_the_headline_says_how_it_was_scored(tmp_path):
    """Issue 38, item 5: report.md and report.json say how the held-out set was chosen: a random
    split with its fraction and seed, the run's last part, the complement, or a separate set."""
    cell = REPO / "datasets" / "cells" / "irb120_tracker.yaml"
    simulate(cell, tmp_path / "data", seed=2, n_configurations=60)
    simulate(cell, tmp_path / "other", seed=3, n_configurations=20)
    cases = {
        "random": ({"holdout": 0.25, "seed": 7}, "15 drawn at random, 25% with seed 7", 7),
        "ordered": ({"holdout": 0.25, "split": "ordered"}, "15: the run's last 25%, split: ordered", None),
        "random complement": (
            {"holdout": 0.5, "seed": 1, "complement": True}, "30: the complement of a split, fitted on 50% drawn "
            "at random with seed 1", 1,
        ),
        "separate set": ({"dataset": str(tmp_path / "other")}, "20 from separate validation sets (other)", None),
    }  # fmt: skip
    for kind, (validation, text, seed) in cases.items():
        calibration = fgcal.calibrate(tmp_path / "data", formulation="tracker", model="DH", validation=validation)
        doc = calibration.write_report(tmp_path / kind, plots=False)
        protocol = doc["validation_protocol"]
        assert protocol["kind"] == kind and protocol["text"] == text and protocol["seed"] == seed, protocol
        assert protocol["n_held_out"] == len(calibration.result.problem.test) == doc["headline"]["n_configurations"]
        assert f"({text})" in doc["headline"]["text"]
        assert doc["headline"]["text"] in (tmp_path / kind / "report.md").read_text()


def test_model_auto_times_every_model_it_compares(tmp_path):
    """Issue 38, item 5: with model: auto the report's time covered only the chosen model."""
    simulate(REPO / "datasets" / "cells" / "irb120_tracker.yaml", tmp_path / "data", seed=2, n_configurations=40)
    timing = fgcal.calibrate(tmp_path / "data", formulation="tracker", model="auto").result.timing
    assert timing["total_s"] > timing["chosen_model_total_s"] > 0
    assert timing["cpu_s"] > timing["chosen_model_cpu_s"] > 0


def test_the_motion_warning_names_the_cause():
    """Issue 38, item 5: a lost-motion term hidden because its joint is barely seen (its offset
    fixed too) was blamed on "one side, one speed"."""
    from fgcal.calibration.identifiability import Identifiability, motion_warning

    reasons = {
        "lm2": "a combination of other parameters (+1 theta2); information left 0.01",
        "lm6": "a combination of other parameters (+1 theta6); information left 0.01",
        "theta6": "no effect on the measurements (information 1e-3)",
    }
    text = motion_warning(Identifiability([], reasons, np.zeros(0), 1.0, 10, {"lm2": ["theta2"]}))
    same_way, unseen = text.split("; the motion-history terms ")
    assert "lm2" in same_way and "one side, at one speed" in same_way and "lm6" not in same_way
    assert unseen.startswith("lm6 stay at zero because the data barely see joint 6"), unseen
