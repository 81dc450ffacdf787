"""k-fold cross-validation (validation: {folds: k}, issue 40 item 6): on the real FARO set each
fold's held-out figures are what the separate run of that fold gives, and the pooled RMS is in
the headline and report.json."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import SHARED

from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.cross_validation import cross_validate
from fgcal.calibration.problem import fold_split
from fgcal.calibration.run import calibrate
from fgcal.commands.cli import main

FARO = SHARED / "data" / "irb120_faro"


def test_the_folds_part_every_configuration_once():
    held = [fold_split(103, 5, k, "random", 7)[1] for k in range(1, 6)]
    assert sorted(np.concatenate(held).tolist()) == list(range(103))
    assert [len(h) for h in held] == [21, 21, 21, 20, 20]
    fit, test = fold_split(10, 5, 2, "ordered", 0)
    assert test.tolist() == [2, 3] and fit.tolist() == [0, 1, 4, 5, 6, 7, 8, 9]


@pytest.mark.skipif(not FARO.exists(), reason="../shared/data/irb120_faro is not present")
def test_each_fold_is_its_separate_run_on_faro(tmp_path):
    """The acceptance on the real FARO set (model DH, the cheapest: the folds' bookkeeping is
    what is checked): every fold's held-out RMS and prediction are its separate run's."""
    from fgcal.data.faro import convert_faro

    convert_faro(FARO, tmp_path / "faro")
    config = CalibrationConfig.defaults(tmp_path / "faro", formulation="tracker", model="DH",
                                        validation={"folds": 5, "seed": 0})  # fmt: skip
    result = cross_validate(config, calibrate)
    cv = result.cross_validation
    assert cv["n_held_out"] == 1000 and len(result.problem.test) == 0  # the reported fit is on all
    for k, row in enumerate(cv["per_fold"], 1):
        alone = calibrate(dataclasses.replace(config, fold=k))
        assert row["n_held_out"] == len(alone.problem.test) == 200
        assert row["after_rms_m"] == alone.validation["after"]["tool_point"].rms, k
        assert row["predicted_rms_m"] == alone.prediction.rms, k
    counts = np.array([r["n_held_out"] for r in cv["per_fold"]])
    per_fold = np.array([r["after_rms_m"] for r in cv["per_fold"]])
    # Pooled over the configurations (each measures the same reflectors): the folds' mean square.
    assert np.isclose(cv["pooled_after_rms_m"], np.sqrt(np.sum(counts * per_fold**2) / counts.sum()), rtol=1e-3)


def test_the_pooled_figures_are_the_headline(tmp_path, capsys):
    assert main(["simulate", "irb120_tracker", "--out", str(tmp_path / "sim"), "--n", "40", "--seed", "1", "-q"]) == 0
    (tmp_path / "cv.yaml").write_text("dataset: sim\nformulation: tracker\nvalidation: {folds: 4, seed: 0}\n")
    assert main(["calibrate", str(tmp_path / "cv.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    cv = report["cross_validation"]
    assert len(cv["per_fold"]) == 4 and cv["n_held_out"] == 40
    assert report["headline"]["after_m"]["rms"] == cv["pooled_after_rms_m"]
    assert report["validation_protocol"]["kind"] == "4-fold cross-validation"
    assert "in 4 folds (random, seed 0)" in report["headline"]["text"]


@pytest.mark.parametrize(("validation", "field"), [
    ("{fold: 2}", "validation.fold"), ("{folds: 5, holdout: 0.2}", "validation.holdout"),
    ("{folds: 5, fold: 6}", "validation.fold"), ("{folds: 5, complement: true}", "validation.complement"),
    ("{folds: 1}", "validation.folds"), ("{folds: 11}", "validation.folds"),
])  # fmt: skip
def test_folds_that_cannot_be_are_refused(validation, field, tmp_path, capsys):
    assert main(["simulate", "irb120_tracker", "--out", str(tmp_path / "sim"), "--n", "20", "-q"]) == 0
    (tmp_path / "c.yaml").write_text(f"dataset: sim\nvalidation: {validation}\n")
    assert main(["calibrate", str(tmp_path / "c.yaml"), "--out", str(tmp_path / "o"), "--no-plots"]) == 2
    assert f"c.yaml: {field}" in capsys.readouterr().err


def test_a_trees_folds_are_pooled_per_tip(tmp_path, capsys):
    """On a tree the per-tip held-out figures are the folds' pooled, as the headline's are (the
    report read "nothing is held out" for the fit on all)."""
    assert main(["simulate", "dual_arm_tracker", "--out", str(tmp_path / "sim"), "--n", "120", "--seed", "1",
                 "-q"]) == 0  # fmt: skip
    (tmp_path / "cv.yaml").write_text("dataset: sim\nformulation: tracker\nvalidation: {folds: 3, seed: 0}\n")
    assert main(["calibrate", str(tmp_path / "cv.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    by_tip, pooled = report["validation"]["by_tip"], report["headline"]["after_m"]["rms"]
    assert report["fit_by_tip"] is None and list(by_tip) == ["left_hand", "right_hand"]
    counts = np.array([e["n_errors"] for e in by_tip.values()])
    after = np.array([e["after_rms_m"] for e in by_tip.values()])
    assert np.isclose(np.sqrt(np.sum(counts * after**2) / counts.sum()), pooled, rtol=1e-9)
    assert "Fitting residuals per tip" not in (tmp_path / "out" / "report.md").read_text()
