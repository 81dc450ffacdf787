"""Measurement setups beyond the camera and the 3D tracker, each simulated and calibrated end
to end against the simulation's truth: touch points (a probe seated in fixed sockets), a
positioner under a tracker, tracker references, separate validation sets. (The 6D probe, the
ballbar and the static camera: test_instruments.py.)"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, calibrate

from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.run import calibrate as calibrate_untouched
from fgcal.core.errors import InputError
from fgcal.data.dataset import load_dataset
from fgcal.simulation.simulate import simulate

TOUCH_CELL = REPO / "datasets" / "cells" / "seven_axis_touch.yaml"
# What the cell's engineer knows: the arm's shoulder and elbow carry its weight (the cell's
# truth has compliance there), and the seating repeatability and the plate's measurement.
TOUCH_CONFIG = {
    "formulation": "touch",
    "compliant_joints": [2, 4],
    "noise": {"touch_sigma": 5e-6, "spacing_sigma": 3e-6},
}


@pytest.fixture(scope="module")
def touch_sims(bundled_sim) -> dict[int, Path]:
    return {seed: bundled_sim(TOUCH_CELL.stem, seed) for seed in (1, 2)}


@pytest.mark.parametrize("seed", [1, 2])
def test_touch_points_calibrate_a_seven_axis_urdf_arm(touch_sims, seed):
    """Issue 12 acceptance: a 7-axis arm loaded from URDF, a probe seated in five sockets with
    known spacing, no instrument. The held-out error against the truth (rigid gauge removed) is
    at most 1.5x its prediction and at least 50x below the nominal model's; against the held-out
    touches themselves, likewise. (Seeds 1-8 gave truth / predicted 0.85-1.20, held-out touches /
    predicted 0.88-1.12, improvement 230-540x.)"""
    dataset = load_dataset(touch_sims[seed])
    assert dataset.robot.n_joints == 7 and str(dataset.header["robot"]).endswith(".urdf")
    config = CalibrationConfig.defaults(touch_sims[seed], **TOUCH_CONFIG)
    measured = calibrate_untouched(config)  # not scored with the truth: the held-out touches
    predicted = measured.measured_prediction.rms
    assert measured.validation["after"]["tool_point"].rms <= 1.5 * predicted
    assert measured.fit.consistent

    result = calibrate(config)
    assert result.truth is not None
    before = result.validation["before"]["tool_point"].rms
    after = result.validation["after"]["tool_point"].rms
    assert after <= 1.5 * result.prediction.rms
    assert after * 50 <= before


def test_touch_points_without_known_distances_lose_the_scale(touch_sims, tmp_path):
    """Without a known distance every length can grow by one factor and the touches agree as
    well: the identifiability analysis finds one more combination of lengths unidentifiable."""
    data = tmp_path / "data"
    shutil.copytree(touch_sims[1], data)
    header = yaml.safe_load((data / "dataset.yaml").read_text())
    header["measured"].remove("point_distances")
    del header["files"]["point_distances"]
    (data / "dataset.yaml").write_text(yaml.safe_dump(header))
    shutil.rmtree(data / "truth")
    with_scale = calibrate_untouched(CalibrationConfig.defaults(touch_sims[1], **TOUCH_CONFIG))
    without = calibrate_untouched(CalibrationConfig.defaults(data, **TOUCH_CONFIG))
    # Judged at the solution: at the start the residuals (120 sigma) change with the scale.
    assert len(without.final_identifiability.identifiable) == len(with_scale.final_identifiability.identifiable) - 1
    # The lost direction is a combination (which parameter is fixed depends on the pivoting).
    lost = {n: r for n, r in without.final_identifiability.unidentifiable.items() if r.startswith("at the solution")}
    assert any("a combination of other parameters" in r for r in lost.values()), lost


def test_a_weak_scale_of_compliant_touches_is_not_released(bundled_sim, tmp_path):
    """Issue 23: with compliances (DH,s,e), touches without a known distance determine the
    common scale only through the gravity deflections, each length alone clearly, all together
    below min_information. The selection now drops a length of that weak direction, so the
    scale stays at the nominal model's: the held-out error falls (it was 110 mm after
    calibration against 0.8 mm before)."""
    from fgcal.calibration.config import load_config

    data = tmp_path / "data"
    shutil.copytree(bundled_sim("seven_axis_touch", 2), data)
    header = yaml.safe_load((data / "dataset.yaml").read_text())
    header["measured"].remove("point_distances")
    del header["files"]["point_distances"]
    (data / "dataset.yaml").write_text(yaml.safe_dump(header))
    result = calibrate(load_config(data / "calibration.yaml"))
    singular = result.final_identifiability.singular_values
    assert singular.min() >= result.config.min_information
    score = next(iter(result.validation["after"]))
    before, after = result.validation["before"][score].rms, result.validation["after"][score].rms
    assert after < before / 2, (before, after)


def test_noise_free_touches_are_exact(tmp_path):
    """With exact seating and exact distances the calibration reproduces the true probe
    positions to below a micrometre: the formulation, its Jacobians and the simulation agree.
    (Not to 1e-9: a fixed redundant parameter is absorbed by its partners to first order only;
    the second order of 0.05 deg deviations leaves about 3e-7 m.)"""
    cell = yaml.safe_load(TOUCH_CELL.read_text())
    cell["robot"] = str(TOUCH_CELL.parent / cell["robot"])
    cell["noise"] = {"touch_sigma": 0.0, "spacing_sigma": 0.0}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    simulate(tmp_path / "cell.yaml", tmp_path / "data", seed=3)
    config = CalibrationConfig.defaults(
        tmp_path / "data", **{**TOUCH_CONFIG, "noise": {"touch_sigma": 1e-9, "spacing_sigma": 1e-9}}
    )
    result = calibrate(config)
    assert result.validation["after"]["tool_point"].rms < 1e-6


def _write(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")


@pytest.mark.parametrize(
    ("table", "text", "message"),
    [
        ("point_distances.csv", "point_a,point_b,distance\ns1,s9,0.5\n", "point 's9' is never touched"),
        ("point_distances.csv", "point_a,point_b,distance\ns1,s1,0.5\n", "two different points"),
        ("point_distances.csv", "point_a,point_b,distance\ns1,s2,-0.5\n", "must be > 0"),
        ("point_distances.csv", "point_a,point_b,distance\ns1,s2,0.5\ns2,s1,0.5\n", "given twice"),
    ],
)
def test_bad_touch_tables_name_the_file_and_line(touch_sims, tmp_path, table, text, message):
    data = tmp_path / "data"
    shutil.copytree(touch_sims[1], data)
    _write(data / table, text)
    with pytest.raises(InputError, match=message) as error:
        load_dataset(data)
    assert table in str(error.value)


def test_a_point_touched_once_is_refused(touch_sims, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(touch_sims[1], data)
    rows = (data / "touch_points.csv").read_text().splitlines()
    kept = [rows[0]] + [r for r in rows[1:] if not r.endswith(",s3")] + [f"{rows[1].split(',')[0]},s3"]
    _write(data / "touch_points.csv", "\n".join(kept) + "\n")
    config = CalibrationConfig.defaults(data, **{**TOUCH_CONFIG, "validation": {"holdout": 0.0}})
    with pytest.raises(InputError, match="'s3' is touched 1 times"):
        calibrate_untouched(config)


def test_sockets_only_a_validation_set_touches_are_scored_leave_one_out(touch_sims, tmp_path):
    """Issue 22, item 7: a validation session of the same arm touching two sockets the fit never
    touched (and one it did). Before, it was refused, naming the fitting set's touch_points.csv;
    now each new socket is scored at each touch against where its other touches put it, and
    the held-out error is within 1.5x of its prediction and 20x below the nominal model's."""
    cell = yaml.safe_load(TOUCH_CELL.read_text())
    cell["robot"] = str(TOUCH_CELL.parent / cell["robot"])
    cell["touch"]["points"] = [
        {"name": "v1", "xyz": [600, -100, 180]},
        {"name": "v2", "xyz": [500, 200, 250]},
        {"name": "s1", "xyz": [550, -250, 150]},
    ]
    cell["touch"]["touches_per_point"] = 8
    cell["touch"]["known_distances"] = False
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    simulate(tmp_path / "cell.yaml", tmp_path / "validation", seed=1)  # seed 1: the fit's true robot
    config = CalibrationConfig.defaults(
        touch_sims[1], **{**TOUCH_CONFIG, "validation": {"dataset": str(tmp_path / "validation")}}
    )
    result = calibrate_untouched(config)
    assert result.problem.observations.names == ("s1", "s2", "s3", "s4", "s5")
    assert [name for name, _ in result.test_observations.test_points] == ["v1", "v2"]
    before, after = (result.validation[k]["tool_point"] for k in ("before", "after"))
    assert len(after.errors) == 24
    assert after.rms <= 1.5 * result.prediction.rms and after.rms * 20 <= before.rms, (after.rms, result.prediction)


def _positioner_cell(tmp_path: Path, table_height_mm: float) -> Path:
    """A two-axis positioner (bundled) measured by a tracker with three reflectors 1 m from the
    table centre; ``table_height_mm`` puts the table centre above the tilt axis (0: on it)."""
    robot = yaml.safe_load((REPO / "datasets" / "robots" / "positioner_2axis.yaml").read_text())
    robot["joints"][1]["origin"]["xyz"] = [0, 0, table_height_mm]
    (tmp_path / "positioner.yaml").write_text(yaml.safe_dump(robot))
    cell = {
        "name": "positioner tracker cell",
        "robot": "positioner.yaml",
        "units": {"length": "mm", "angle": "deg"},
        "payload": {"mass": 40, "com": [0, 0, 150]},
        "tracker": {
            "pose": {"xyz": [2500, -1500, 1200], "rpy": [0, 0, 150]},
            "targets": [[1000, 0, 0], [-500, 866, 0], [-500, -866, 0]],
        },
        "noise": {"tracker_sigma": 0.02},
        "perturbation": {"length": 0.5, "angle": 0.05, "distortion": 0.05, "compliance": [1e-7, 1e-6]},
        "design": {"kind": "space_filling", "n_configurations": 60},
    }
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    return tmp_path / "cell.yaml"


@pytest.mark.parametrize("seed", [2, 3])
def test_positioner_with_far_reflectors_starts_right_with_defaults(tmp_path, seed):
    """Issue 12: a 2-axis positioner whose table centre (the flange) sits on its axes, three
    reflectors 1 m out. The flange origins never move, so they say nothing about the tracker's
    orientation; the single-start initialisation ended stage 0 at 0.45 m for these seeds. With
    the default settings the calibration now starts from the right minimum and ends at the
    noise."""
    simulate(_positioner_cell(tmp_path, 0.0), tmp_path / "data", seed=seed)
    config = CalibrationConfig.defaults(tmp_path / "data", formulation="tracker", noise={"tracker_sigma": 2e-5})
    result = calibrate(config)
    assert result.stages[0].residual_rms["m"] < 1e-3
    before, after = (result.validation[k]["tool_point"].rms for k in ("before", "after"))
    assert after <= 1.5 * result.prediction.rms and after * 20 <= before


def test_data_that_do_not_fit_are_refused_without_writing_a_robot(tmp_path):
    """Tracker rows attached to the wrong configurations: stage 0 cannot explain them (0.5 m per
    coordinate against 20 um of noise), and fgcal says so with the likely causes, exit status 2,
    no robot written."""
    import csv
    import subprocess
    import sys

    simulate(_positioner_cell(tmp_path, 250.0), tmp_path / "data", seed=2)
    path = tmp_path / "data" / "tracker_points.csv"
    rows = list(csv.reader(path.open()))
    configs = sorted({r[0] for r in rows[1:]})
    shuffled = dict(zip(configs, np.random.default_rng(0).permutation(configs), strict=True))
    body = sorted(([shuffled[r[0]], *r[1:]] for r in rows[1:]), key=lambda r: r[0])
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows([rows[0], *body])
    (tmp_path / "calib.yaml").write_text("dataset: data\nformulation: tracker\nnoise: {tracker_sigma: 2.0e-5}\n")
    out = tmp_path / "out"
    run = subprocess.run(
        [sys.executable, "-m", "fgcal", "calibrate", str(tmp_path / "calib.yaml"), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,  # not the checkout: its fgcal/ is not the installed package (factors/ is mapped in)
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "cannot be explained" in run.stderr and "rows shifted" in run.stderr
    assert not (out / "calibrated_robot.yaml").exists()


def test_tracker_references_report_drift_and_misreads(tmp_path):
    """Three reflectors fixed in the cell, read at every configuration: one drifts 0.2 mm along x
    over the session, one has two misreads of 30 mm; the check recovers the drift, names the
    misreads, and flags nothing in the clean reflector."""
    from fgcal.calibration.references import reference_check
    from fgcal.data.dataset import write_csv

    simulate(_positioner_cell(tmp_path, 250.0), tmp_path / "data", seed=1)
    dataset = load_dataset(tmp_path / "data")
    rng = np.random.default_rng(0)
    n = len(dataset.configs)
    rows = []
    for name, origin in (("r1", [2.0, 1.0, 0.0]), ("r2", [2.5, -1.0, 0.2]), ("r3", [1.5, 0.0, -0.3])):
        xyz = np.array(origin) + rng.normal(0.0, 2e-5, (n, 3))
        if name == "r1":
            xyz[:, 0] += np.linspace(0.0, 2e-4, n)
        if name == "r2":
            xyz[[10, 40]] += [0.03, 0.0, 0.0]
        rows += [[c, name, *map(float, p)] for c, p in zip(dataset.configs, xyz, strict=True)]
    write_csv(tmp_path / "data" / "tracker_references.csv", ["config", "target", "x", "y", "z"], rows)
    header = yaml.safe_load((tmp_path / "data" / "dataset.yaml").read_text())
    header["files"]["tracker_references"] = "tracker_references.csv"
    header["measured"].append("tracker_references")
    (tmp_path / "data" / "dataset.yaml").write_text(yaml.safe_dump(header))

    check = reference_check(load_dataset(tmp_path / "data"), 2e-5)
    r1, r2, r3 = (check["targets"][k] for k in ("r1", "r2", "r3"))
    assert abs(r1["drift_m"][0] - 1.8e-4) < 3e-5 and r1["misreads"] == []  # 90 % of 0.2 mm between the tenths
    assert r2["misreads"] == [str(dataset.configs[10]), str(dataset.configs[40])]
    assert r2["largest_misread_m"] == pytest.approx(0.03, abs=1e-4) and r3["misreads"] == []
    assert all(abs(t["noise_sigma_m"] - 2e-5) < 6e-6 for t in (r1, r2, r3))


@pytest.mark.skipif(not (REPO.parent / "shared" / "data" / "irb120_faro").exists(), reason="../shared absent")
def test_real_tracker_references(tmp_path):
    """The FARO set's fixed reflectors: ref3 has gross outliers of hundreds of mm (its README);
    the check names them and nothing in ref1 and ref2, and the references drift together by a
    few hundredths of a mm over the session."""
    from fgcal.calibration.references import reference_check
    from fgcal.data.faro import convert_faro

    convert_faro(REPO.parent / "shared" / "data" / "irb120_faro", tmp_path / "faro")
    check = reference_check(load_dataset(tmp_path / "faro"), 5e-5)
    ref1, ref2, ref3 = (check["targets"][k] for k in ("ref1", "ref2", "ref3"))
    assert ref1["misreads"] == [] and ref2["misreads"] == []
    assert 1 <= len(ref3["misreads"]) <= 20 and ref3["largest_misread_m"] > 0.1
    assert 1e-5 < check["common_drift_norm_m"] < 2e-4


TRACKER_CELL = REPO / "datasets" / "cells" / "irb120_tracker.yaml"


@pytest.fixture(scope="module")
def validation_sets(tmp_path_factory) -> Path:
    """A tracker session (cell irb120_tracker, seed 1) and a separate validation session of the
    same robot: 40 other configurations measuring one test point elsewhere on the tool
    (``test1``), which the fit never sees."""
    from fgcal.data.dataset import write_csv
    from fgcal.model.robot_io import load_robot

    root = tmp_path_factory.mktemp("validation_sets")
    cell = yaml.safe_load(TRACKER_CELL.read_text())
    cell["tracker"]["targets"] = [[60, 20, 80]]
    (root / "test_cell.yaml").write_text(yaml.safe_dump(cell))
    robot = load_robot("abb_irb120")
    low, high = np.maximum(robot.limits[:, 0], -np.pi), np.minimum(robot.limits[:, 1], np.pi)
    q = np.random.default_rng(99).uniform(low, high, (40, 6))
    write_csv(
        root / "q.csv",
        ["config", *[f"q{i}" for i in range(1, 7)]],
        [[f"v{i}", *map(float, r)] for i, r in enumerate(q)],
    )
    simulate(TRACKER_CELL, root / "fit", seed=1)
    simulate(root / "test_cell.yaml", root / "test", seed=1, configurations=root / "q.csv")
    for name in ("tracker_points.csv", "dataset.yaml"):  # the test point has a name of its own
        path = root / "test" / name
        path.write_text(path.read_text().replace(",t1,", ",test1,").replace("- t1", "- test1"))
    return root


@pytest.mark.parametrize("declared", [False, True])
def test_a_separate_validation_set_scores_its_own_test_point(validation_sets, declared):
    """Issue 12: ``validation: {dataset: DIR}``. The whole first session fits; the second one's
    test point is scored at its leave-one-out position, or at its declared drawing position
    carried onto the fitted reflectors. Either way the held-out error is within 1.5x of its
    prediction and 20x below the nominal model's. (Seeds 1-3: after / predicted 1.04-1.11 both
    ways, 28-30 um against 0.95-1.2 mm before.)"""
    validation = {"dataset": str(validation_sets / "test")}
    if declared:  # the tool's drawing: the three reflectors and the test point
        validation["tool_points"] = {
            "t1": [0.04, 0.0, 0.03],
            "t2": [-0.02, 0.035, 0.03],
            "t3": [-0.02, -0.035, 0.03],
            "test1": [0.06, 0.02, 0.08],
        }
    config = CalibrationConfig.defaults(
        validation_sets / "fit", formulation="tracker", noise={"tracker_sigma": 1.5e-5}, validation=validation
    )
    result = calibrate_untouched(config)
    assert len(result.problem.fit) == 100 and len(result.problem.test) == 40
    assert result.problem.observations.names == ("t1", "t2", "t3")
    before, after = (result.validation[k]["tool_point"].rms for k in ("before", "after"))
    assert after <= 1.5 * result.measured_prediction.rms and after * 20 <= before


def test_several_validation_sets_are_scored_each(validation_sets, tmp_path):
    """Issue 22, item 10: validation.dataset takes a list; the report says which sets it scored
    (with the fitting dataset's own held-out configurations), each one's figures, and how its
    test points were scored."""
    from fgcal.data.dataset import write_csv
    from fgcal.reports.calibration import write_report

    q = np.random.default_rng(7).uniform(-1.0, 1.0, (20, 6))
    write_csv(tmp_path / "q.csv", ["config", *[f"q{i}" for i in range(1, 7)]],
              [[f"w{i}", *map(float, r)] for i, r in enumerate(q)])  # fmt: skip
    simulate(validation_sets / "test_cell.yaml", tmp_path / "test2", seed=1, configurations=tmp_path / "q.csv")
    for name in ("tracker_points.csv", "dataset.yaml"):
        path = tmp_path / "test2" / name
        path.write_text(path.read_text().replace(",t1,", ",test1,").replace("- t1", "- test1"))
    sets = [str(validation_sets / "test"), str(tmp_path / "test2")]
    config = CalibrationConfig.defaults(
        validation_sets / "fit", formulation="tracker", noise={"tracker_sigma": 1.5e-5},
        validation={"dataset": sets, "holdout": 0.2},
    )  # fmt: skip
    result = calibrate_untouched(config)
    assert len(result.problem.test) == 20 + 40 + 20
    doc = write_report(result, tmp_path / "report", plots=False)
    scored = doc["validation"]["sets"]
    assert [entry["dataset"] for entry in scored] == ["held out of the fitting dataset", *sets]
    assert [entry["n_configurations"] for entry in scored] == [20, 40, 20]
    assert all(entry["scores"]["position_error_m"]["rms"] < 1e-4 for entry in scored)
    assert doc["validation"]["test_points"] == {"test1": "leave-one-out"}
    text = (tmp_path / "report" / "report.md").read_text()
    assert all(path in text for path in sets) and "test1 (leave-one-out)" in text


def test_a_validation_set_of_another_robot_is_refused(validation_sets, tmp_path):
    simulate(TOUCH_CELL, tmp_path / "other", seed=1)
    config = CalibrationConfig.defaults(
        validation_sets / "fit", formulation="tracker", validation={"dataset": str(tmp_path / "other")}
    )
    with pytest.raises(InputError, match=r"validation.dataset.*same robot"):
        calibrate_untouched(config)
