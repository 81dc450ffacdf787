"""The bundled cells with several chains, end to end (issue 28's acceptance): a dual-arm upper
body on a compliant torso with a coupled joint and a mass scale, and a robot with its
positioner, each simulated and calibrated with the configuration fgcal simulate writes."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO

from fgcal.commands.cli import main

TORSO = ("a1", "alpha1", "theta2", "a2", "alpha2", "theta3", "a3", "alpha3", "theta4", "kx2", "ky2", "kz2",
         "kx3", "ky3", "kz3", "mass.arms")  # fmt: skip


def _calibrate(data, out, capsys) -> dict:
    assert main(["calibrate", str(data / "calibration.yaml"), "--out", str(out), "--no-plots"]) == 0
    capsys.readouterr()
    return json.loads((out / "report.json").read_text())


@pytest.fixture(scope="module")
def dual_arm(tmp_path_factory):
    root = tmp_path_factory.mktemp("dual_arm")
    assert main(["simulate", "dual_arm_tracker", "--out", str(root / "data"), "--seed", "1"]) == 0
    return root


def _copy_dataset(source: Path, data: Path, truth: bool = False) -> Path:
    """A copy of a simulated dataset's files (and its truth: scored against it) to change."""
    for folder in ("", "truth") if truth else ("",):
        (data / folder).mkdir(parents=True)
        for file in (source / folder).iterdir():
            if file.is_file():
                (data / folder / file.name).write_bytes(file.read_bytes())
    return data


def _held_out(report: dict) -> tuple[float, float, float]:
    validation = report["validation"]
    return (
        validation["before"]["position_error_m"]["rms"],
        validation["after"]["position_error_m"]["rms"],
        validation["predicted_position_sigma_m"]["rms"],
    )


def test_dual_arm_cell_calibrates_to_its_prediction_with_compliances_and_mass_ratio(dual_arm, capsys):
    report = _calibrate(dual_arm / "data", dual_arm / "both", capsys)
    before, after, predicted = _held_out(report)
    assert report["validation"]["reference"] == "ground truth"
    assert before / after >= 50.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    parameters = report["parameters"]
    recovered = [n for n, p in parameters.items() if n[0] == "k" and p["status"] == "estimated"] + ["mass.arms"]
    assert {"kx2", "kz3", "ky6", "kz13", "mass.arms"} <= set(recovered)
    for name in recovered:
        p = parameters[name]
        assert p["status"] == "estimated"
        assert abs(p["truth"] - p["estimate"]) <= 3 * p["sigma"], (name, p)
    assert parameters["mass.arms"]["truth"] != 1.0  # the simulated arms are off their drawing's mass
    # The report says what each hand's data alone determine of the torso, and all determine more.
    chains = report["chains"]
    assert chains["tips"] == ["left_hand", "right_hand"]
    shared = chains["parameters"]
    assert set(TORSO) <= set(shared) and not any(n.endswith(("5", "12")) and n != "mass.arms" for n in shared)
    for name in TORSO:
        alone = [s for s in shared[name]["sigma_by_tip"].values() if s is not None]
        assert alone and all(shared[name]["sigma_all"] < s for s in alone), (name, shared[name])
    text = (dual_arm / "both" / "report.md").read_text()
    assert "## Shared by the chains" in text and "| left_hand alone | right_hand alone | all |" in text
    # Each chain on its own (issue 40, item 7): the pooled figures are the tips' together.
    by_tip = report["validation"]["by_tip"]
    assert list(by_tip) == ["left_hand", "right_hand"] and "Held out per tip" in text
    counts = np.array([entry["n_errors"] for entry in by_tip.values()])
    for key, pooled in (("before_rms_m", before), ("after_rms_m", after), ("predicted_rms_m", predicted)):
        tips = np.array([entry[key] for entry in by_tip.values()])
        assert np.isclose(np.sqrt(np.sum(counts * tips**2) / counts.sum()), pooled, rtol=1e-9), key
    for tip, entry in by_tip.items():
        assert entry["before_rms_m"] / entry["after_rms_m"] >= 50.0, (tip, entry)
        assert 1 / 1.5 <= entry["after_rms_m"] / entry["predicted_rms_m"] <= 1.5, (tip, entry)


def test_each_tips_held_out_measurements_without_a_truth(dual_arm, capsys):
    """Without a truth the per-tip figures are the held-out measurements' (tracker points on
    each hand), with their prediction (the noise in it)."""
    data = _copy_dataset(dual_arm / "data", dual_arm / "no_truth")
    report = _calibrate(data, dual_arm / "no_truth_report", capsys)
    assert report["validation"]["reference"] == "held-out measurements"
    by_tip = report["validation"]["by_tip"]
    assert list(by_tip) == ["left_hand", "right_hand"]
    counts = np.array([entry["n_errors"] for entry in by_tip.values()])
    after = np.array([entry["after_rms_m"] for entry in by_tip.values()])
    pooled = report["validation"]["after"]["position_error_m"]["rms"]
    assert np.isclose(np.sqrt(np.sum(counts * after**2) / counts.sum()), pooled, rtol=1e-9)
    for tip, entry in by_tip.items():
        assert entry["before_rms_m"] > 10 * entry["after_rms_m"], (tip, entry)
        assert 1 / 1.5 <= entry["after_rms_m"] / entry["predicted_rms_m"] <= 1.5, (tip, entry)


@pytest.mark.parametrize("hand", ["t1", "t2"])
def test_each_arm_alone_knows_the_torso_less_than_both(dual_arm, hand, capsys):
    """Calibrating with one hand's reflector only: the torso's parameters estimated both ways
    have larger sigmas than with both hands' data."""
    both = dual_arm / "both" / "report.json"
    if not both.exists():
        _calibrate(dual_arm / "data", dual_arm / "both", capsys)
    data = _copy_dataset(dual_arm / "data", dual_arm / f"only_{hand}", truth=True)
    with open(dual_arm / "data" / "tracker_points.csv", newline="") as f:
        rows = list(csv.reader(f))
    with open(data / "tracker_points.csv", "w", newline="") as f:
        csv.writer(f).writerows([rows[0], *(r for r in rows[1:] if r[1] == hand)])
    alone = _calibrate(data, dual_arm / f"report_{hand}", capsys)["parameters"]
    joint = json.loads(both.read_text())["parameters"]
    compared = [n for n in TORSO if alone[n]["status"] == joint[n]["status"] == "estimated"]
    assert len(compared) >= 10, compared
    for name in compared:
        assert joint[name]["sigma"] < alone[name]["sigma"], (name, joint[name]["sigma"], alone[name]["sigma"])


def test_robot_and_positioner_cell_calibrates_to_its_prediction(tmp_path, capsys):
    assert main(["simulate", "robot_positioner_tracker", "--out", str(tmp_path / "data"), "--seed", "1"]) == 0
    dataset = yaml.safe_load((tmp_path / "data" / "dataset.yaml").read_text())
    assert set(dataset["tracker"]["tips"].values()) == {"flange", "table"}
    report = _calibrate(tmp_path / "data", tmp_path / "out", capsys)
    before, after, predicted = _held_out(report)
    assert before / after >= 50.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    # The geometry's estimates are effective values (the tracker's frame takes the base, and a
    # redundant parameter's deviation goes to those it is a combination of); the compliances,
    # the positioner's tilt axis's among them, are the truth's.
    # Robot and positioner share only the base, which the tracker's frame fixes: nothing shared.
    assert report["chains"]["tips"] == ["flange", "table"] and report["chains"]["parameters"] == {}
    assert (
        "No estimated parameter moves more than one tip's measurements" in (tmp_path / "out" / "report.md").read_text()
    )
    compliances = {n: p for n, p in report["parameters"].items() if n[0] == "k" and p["status"] == "estimated"}
    assert "kz7" in compliances
    for name, p in compliances.items():
        assert abs(p["truth"] - p["estimate"]) <= 3 * p["sigma"], (name, p)


DUAL_ARM = REPO / "datasets" / "robots" / "dual_arm_torso.yaml"
DUAL_CELL = REPO / "datasets" / "cells" / "dual_arm_tracker.yaml"


def _joint(i: int, key: str, value):
    def change(doc: dict) -> None:
        doc["joints"][i][key] = value

    return change


def _top(key: str, value):
    def change(doc: dict) -> None:
        doc[key] = value

    return change


def _follower(i: int, coupling: dict):
    def change(doc: dict) -> None:
        doc["joints"][i].pop("limits")
        doc["joints"][i]["coupling"] = coupling

    return change


# (case, change of the dual-arm robot file, field named)
ROBOT_CASES = [
    ("coupling_to_itself", _joint(3, "coupling", {"joints": [4], "coefficients": [1]}), "joints[3].coupling.joints[0]"),
    ("coupling_to_nothing", _joint(3, "coupling", {"joints": [], "coefficients": []}), "coupling.joints"),
    ("coupling_beyond", _joint(3, "coupling", {"joints": [40], "coefficients": [1]}), "coupling.joints[0]"),
    ("coupling_short", _joint(3, "coupling", {"joints": [2, 3], "coefficients": [1]}), "coupling.coefficients"),
    ("coupling_zero", _joint(3, "coupling", {"joints": [2], "coefficients": [0]}), "coupling.coefficients"),
    ("coupling_nan_offset", _joint(3, "coupling", {"joints": [2], "coefficients": [1], "offset": float("nan")}),
     "coupling.offset"),
    ("coupling_with_limits", _joint(3, "limits", [-10, 10]), "joints[3].limits"),
    ("coupling_unknown_key", _joint(3, "coupling", {"joints": [2], "coefficients": [1], "gain": 2}), "coupling.gain"),
    ("coupled_leader", _follower(4, {"joints": [4], "coefficients": [1]}), "joints[4].coupling.joints"),
    ("mass_group_beyond", _top("mass_groups", {"arms": [5, 99]}), "mass_groups.arms[1]"),
    ("mass_group_twice", _top("mass_groups", {"arms": [5, 6], "hands": [6]}), "mass_groups.hands[0]"),
    ("mass_group_empty", _top("mass_groups", {"arms": []}), "mass_groups.arms"),
    ("mass_group_name", _top("mass_groups", {"the arms": [5]}), "mass_groups.the arms"),
    ("mass_scale_unknown_group", _top("parameters", {"mass.legs": 1.1}), "parameters.mass.legs"),
    ("mass_scale_negative", _top("parameters", {"mass.arms": -1.0}), "parameters.mass.arms"),
    ("coupling_self", _joint(3, "coupling", {"joints": [4], "coefficients": [1]}), "joints[3].coupling.joints[0]"),
]  # fmt: skip


@pytest.mark.parametrize("case, change, field", ROBOT_CASES, ids=[c[0] for c in ROBOT_CASES])
def test_a_damaged_tree_robot_file_is_refused_naming_the_field(case, change, field, tmp_path, capsys):
    doc = yaml.safe_load(DUAL_ARM.read_text())
    change(doc)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["fk", str(tmp_path / "robot.yaml"), *["0"] * 17]) == 2
    error = capsys.readouterr().err
    assert "robot.yaml" in error and field in error and "Traceback" not in error, error


CELL_CASES = [
    ("target_on_no_tip", {"targets": {"left_foot": [[0, 0, 50]]}}, "targets.left_foot"),
    ("targets_not_a_list", {"targets": {"left_hand": 50}}, "targets.left_hand"),
    ("target_nan", {"targets": {"left_hand": [[0, float("nan"), 50]]}}, "targets.left_hand[0]"),
]


@pytest.mark.parametrize("case, tracker, field", CELL_CASES, ids=[c[0] for c in CELL_CASES])
def test_a_damaged_tree_cell_is_refused_naming_the_field(case, tracker, field, tmp_path, capsys):
    doc = yaml.safe_load(DUAL_CELL.read_text())
    doc["tracker"].update(tracker)
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "sim")]) == 2
    error = capsys.readouterr().err
    assert "cell.yaml" in error and field in error and "Traceback" not in error, error


def test_a_mass_scale_needs_mass_groups_and_a_dataset_tip_must_exist(dual_arm, tmp_path, capsys):
    cell = yaml.safe_load((REPO / "datasets" / "cells" / "irb120_tracker.yaml").read_text())
    cell["perturbation"]["mass_scale"] = 0.1
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "sim")]) == 2
    assert "perturbation.mass_scale" in capsys.readouterr().err
    data = _copy_dataset(dual_arm / "data", tmp_path / "data")
    header = yaml.safe_load((data / "dataset.yaml").read_text())
    header["tracker"]["tips"]["t2"] = "right_foot"
    (data / "dataset.yaml").write_text(yaml.safe_dump(header, sort_keys=False))
    assert main(["calibrate", str(data / "calibration.yaml"), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "dataset.yaml" in error and "tracker.tips.t2" in error and "right_foot" in error, error


def test_compensate_addresses_a_tip_by_name(dual_arm, tmp_path, capsys):
    """fgcal compensate --tip right_hand: targets of the right hand, reached in the calibrated
    model; an unknown tip is refused."""
    import numpy as np

    import fgcal

    report = dual_arm / "both"
    if not (report / "calibrated_robot.yaml").exists():
        _calibrate(dual_arm / "data", report, capsys)
    robot = fgcal.load_robot(report / "calibrated_robot.yaml")
    q = np.random.default_rng(1).uniform(robot.limits[:, 0] * 0.5, robot.limits[:, 1] * 0.5, (5, robot.n_joints))
    targets = robot.fk(q, tip="right_hand")[:, :3, 3]
    lines = ["target,x,y,z," + ",".join(f"q{i + 1}" for i in range(robot.n_joints))]
    lines += [
        ",".join([f"p{k}", *map(str, t), *map(str, h + 0.01)]) for k, (t, h) in enumerate(zip(targets, q, strict=True))
    ]
    (tmp_path / "targets.csv").write_text("\n".join(lines) + "\n")
    argv = ["compensate", str(report / "calibrated_robot.yaml"), str(tmp_path / "targets.csv")]
    assert main([*argv, "--out", str(tmp_path / "c.csv"), "--tip", "right_hand", "--targets-frame", "W"]) == 0
    rows = list(csv.DictReader(line for line in (tmp_path / "c.csv").open() if not line.startswith("#")))
    assert [r["status"] for r in rows] == ["ok"] * 5
    solved = np.array([[float(r[f"q{i + 1}"]) for i in range(robot.n_joints)] for r in rows])
    np.testing.assert_allclose(robot.fk(solved, tip="right_hand")[:, :3, 3], targets, atol=2e-6)
    # The left arm (joints 4-10: off the right hand's path) stays at its hints, exactly, though
    # its weight bends the torso the right hand hangs from.
    np.testing.assert_allclose(solved[:, 3:10], q[:, 3:10] + 0.01, rtol=0, atol=1e-12)
    capsys.readouterr()
    assert main([*argv, "--out", str(tmp_path / "d.csv"), "--tip", "left_foot"]) == 2
    assert "--tip" in capsys.readouterr().err


def test_one_mass_scale_of_every_body_is_found_a_combination_of_the_compliances(tmp_path, capsys):
    """k mu t is one product: a mass scale of every body trades exactly against the compliances,
    and the identifiability analysis says so (and fixes it), where a ratio between groups is
    estimated (test above)."""
    robot = yaml.safe_load(DUAL_ARM.read_text())
    robot["mass_groups"] = {"all": list(range(1, 19))}
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(robot, sort_keys=False))
    cell = yaml.safe_load(DUAL_CELL.read_text())
    cell["robot"] = "robot.yaml"
    cell["design"]["n_configurations"] = 120
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell, sort_keys=False))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "data"), "--seed", "1"]) == 0
    report = _calibrate(tmp_path / "data", tmp_path / "out", capsys)
    assert report["parameters"]["mass.all"]["status"] == "fixed"
    reason = report["unidentifiable_reasons"]["mass.all"]
    assert reason.startswith("a combination of other parameters (") and " k" in reason, reason
    assert float(reason.rsplit("information left ", 1)[1]) < 1e-6, reason


def _variant(tmp_path, source: str, change) -> Path:
    cell = yaml.safe_load((REPO / "datasets" / "cells" / f"{source}.yaml").read_text())
    change(cell)
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell, sort_keys=False))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "data"), "--seed", "1"]) == 0
    return tmp_path / "data"


def test_a_static_camera_watches_a_board_on_the_positioners_table(tmp_path, capsys):
    """cell tip: table, a static camera and the board on the positioner's table (the robot's
    joints never move the board): the static-camera formulation on that tip."""

    def change(cell: dict) -> None:
        cell.update(robot="irb120_positioner", tip="table")
        cell.pop("payload")
        cell["static_camera"]["pose"] = {"xyz": [600, 0, 1900], "rpy": [180, 0, 0]}
        cell["perturbation"].update(compliant_joints=[7], compliance=[1e-6, 5e-6])
        cell["design"]["n_configurations"] = 80

    data = _variant(tmp_path, "positioner_static_camera", change)
    assert yaml.safe_load((data / "dataset.yaml").read_text())["tip"] == "table"
    report = _calibrate(data, tmp_path / "out", capsys)
    before, after, predicted = _held_out(report)
    assert report["formulation"] == "static_camera" and before / after >= 10.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    assert report["parameters"]["theta1"]["status"] == "fixed"  # the robot's joints do not move the board


def test_a_6d_probe_on_the_right_hand(tmp_path, capsys):
    """cell tip: right_hand with a 6D probe: the poses formulation on the dual-arm's right hand."""

    def change(cell: dict) -> None:
        cell["tip"] = "right_hand"
        cell["tracker"].update(targets=[[0, 0, 50]], probe={"xyz": [0, 0, 80], "rpy": [0, 0, 0]})

    report = _calibrate(_variant(tmp_path, "dual_arm_tracker", change), tmp_path / "out", capsys)
    before, after, predicted = _held_out(report)
    assert report["formulation"] == "poses" and before / after >= 50.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    assert report["validation"]["scored_point_frame"] == "right_hand"


def test_a_tip_the_robot_lacks_or_a_camera_on_a_tip_is_refused(dual_arm, tmp_path, capsys):
    cell = yaml.safe_load(DUAL_CELL.read_text())
    cell["tip"] = "left_foot"
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "sim")]) == 2
    error = capsys.readouterr().err
    assert "cell.yaml" in error and "tip" in error and "left_foot" in error, error
    seed = yaml.safe_load((REPO / "datasets" / "cells" / "kr125_seed.yaml").read_text())
    seed["tip"] = "flange2"
    (tmp_path / "seed.yaml").write_text(yaml.safe_dump(seed))
    assert main(["simulate", str(tmp_path / "seed.yaml"), "--out", str(tmp_path / "sim")]) == 2
    assert "tip" in capsys.readouterr().err
    data = _copy_dataset(dual_arm / "data", tmp_path / "data")
    header = yaml.safe_load((data / "dataset.yaml").read_text())
    header["tip"] = "nose"
    (data / "dataset.yaml").write_text(yaml.safe_dump(header, sort_keys=False))
    assert main(["calibrate", str(data / "calibration.yaml"), "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "dataset.yaml" in error and "tip" in error and "nose" in error, error


def test_a_test_point_on_the_right_hand_is_scored_on_it(dual_arm, tmp_path, capsys):
    """A reflector only the held-out configurations measure (t3, leave-one-out), on the right
    hand: scored through the right hand's chain, to its prediction (before the fix: 818 mm)."""
    data = _copy_dataset(dual_arm / "data", tmp_path / "data")
    configs = [row[0] for row in csv.reader((data / "configurations.csv").open())][1:]
    test = set(configs[225:])  # split: ordered holds out the last quarter
    rows = list(csv.reader((data / "tracker_points.csv").open()))
    rows[1:] = [[r[0], "t3" if r[1] == "t2" and r[0] in test else r[1], *r[2:]] for r in rows[1:]]
    with open(data / "tracker_points.csv", "w", newline="") as f:
        csv.writer(f).writerows(rows)
    header = yaml.safe_load((data / "dataset.yaml").read_text())
    header["tracker"]["targets"].append("t3")
    header["tracker"]["tips"]["t3"] = "right_hand"
    (data / "dataset.yaml").write_text(yaml.safe_dump(header, sort_keys=False))
    config = yaml.safe_load((data / "calibration.yaml").read_text())
    config["validation"] = {"split": "ordered"}
    (data / "calibration.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    (data / "truth").mkdir()  # scored against the measurements: no truth
    report = _calibrate(data, tmp_path / "out", capsys)
    assert report["validation"]["test_points"] == {"t3": "leave-one-out"}
    measured = report["validation"]["after"]["position_error_m"]["rms"]
    predicted = report["validation"]["predicted_position_sigma_m"]["rms"]
    assert measured < 1e-4 and 1 / 1.5 <= measured / predicted <= 1.5, (measured, predicted)


def test_what_scores_the_flange_alone_is_refused_for_a_tree(tmp_path, capsys):
    for option in (["--rigid-fit"], ["--calibration", str(tmp_path / "none.yaml")]):
        assert main(["export", "dual_arm_torso", "--urdf", str(tmp_path / "d.urdf"), *option]) == 2
        assert f"{option[0]}: dual-arm torso is a tree" in capsys.readouterr().err
    assert main(["export", "dual_arm_torso", "--ur-kinematics", str(tmp_path / "k.yaml")]) == 2
    assert "not laid out as a UR arm" in capsys.readouterr().err


def test_import_csv_puts_reflectors_on_their_tips(dual_arm, tmp_path, capsys):
    """A tracker export and a joint log of the dual-arm robot: the mapping's target_tips put each
    reflector on its hand in the imported dataset (which the importer reads back); an unknown tip
    is refused naming the mapping's field."""
    data = dual_arm / "data"
    joints = [f"q{i}" for i in range(1, 18)]
    mapping = {
        "format": "fgcal-import/1", "robot": "dual_arm_torso", "units": {"length": "m", "angle": "rad"},
        "configurations": {"file": str(data / "configurations.csv"), "config": "config", "joints": joints},
        "tracker_points": {"file": str(data / "tracker_points.csv"), "config": "config", "target": "target",
                           "xyz": ["x", "y", "z"]},
        "target_tips": {"t1": "left_hand", "t2": "right_hand"},
    }  # fmt: skip
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping, sort_keys=False))
    assert main(["import-csv", str(tmp_path / "mapping.yaml"), "--out", str(tmp_path / "imported")]) == 0
    header = yaml.safe_load((tmp_path / "imported" / "dataset.yaml").read_text())
    assert header["tracker"]["tips"] == {"t1": "left_hand", "t2": "right_hand"}
    mapping["target_tips"] = {"t2": "left_foot"}
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping, sort_keys=False))
    capsys.readouterr()
    assert main(["import-csv", str(tmp_path / "mapping.yaml"), "--out", str(tmp_path / "again")]) == 2
    error = capsys.readouterr().err
    assert "mapping.yaml" in error and "target_tips.t2" in error and "left_foot" in error, error


def test_identifiability_judges_only_what_the_stages_release(dual_arm, tmp_path, capsys):
    """Issue 38, item 1: with stages that release theta and kz only (and d, a, alpha), no
    released parameter is fixed as "a combination of" kinds no stage releases (kx, ky, sx, sy);
    those are reported as not released, not as fixed by the data."""
    config = {
        "dataset": str(dual_arm / "data"), "formulation": "tracker", "model": "DH,s,e",
        "noise": {"tracker_sigma": 1.5e-5}, "compliant_joints": list(range(1, 19)),
        "stages": [["theta"], ["kz"], ["theta", "d", "a", "alpha", "kz"]],
    }  # fmt: skip
    (tmp_path / "kz.yaml").write_text(yaml.safe_dump(config))
    assert main(["calibrate", str(tmp_path / "kz.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    released_kinds = {"theta", "d", "a", "alpha", "kz"}
    for name, reason in report["unidentifiable_reasons"].items():
        assert re.sub(r"\d+$", "", name) in released_kinds, (name, reason)
        combination = re.match(r"a combination of other parameters \((.*)\)", reason)
        partners = re.findall(r"[+-][\d.]+ (\w+)", combination.group(1)) if combination else []
        unreleased = [p for p in partners if re.sub(r"\d+$", "", p) not in released_kinds]
        assert not unreleased, (name, reason)
    statuses = {name: p["status"] for name, p in report["parameters"].items()}
    assert statuses["kx10"] == statuses["sx2"] == "not released"
    # kz10 and kz17 were fixed as combinations of kx/ky before; the data determine them.
    assert statuses["kz10"] == statuses["kz17"] == "estimated"


def test_a_trees_report_says_what_each_compliance_moves_and_what_absorbs_a_parameter(dual_arm, tmp_path, capsys):
    """Issue 38, item 6: a compliance of one arm was evaluated at another tip's point and read
    "moves the tool up to 0 mm"; parameters taken by the tracker's pose or the reflectors read
    "no effect on the measurements". Now each compliance moves its own arm's tip, by tip, and
    such parameters are "absorbed by" the unknown that takes them."""
    report = _calibrate(dual_arm / "data", tmp_path / "out", capsys)
    compliances = {n: p for n, p in report["parameters"].items() if n[0] == "k" and p["status"] == "estimated"}
    assert compliances
    for name, entry in compliances.items():
        tips = entry["deflection_at_tips_max_m"]
        assert set(tips) == {"left_hand", "right_hand"}, tips
        assert entry["deflection_at_tool_max_m"] == max(tips.values()) > 1e-6, (name, tips)
    reasons = report["unidentifiable_reasons"]
    absorbed = {n: r for n, r in reasons.items() if r.startswith("absorbed by")}
    assert any(n.startswith("base.") for n in absorbed) and all("tracker" in r or "tool_points" in r or "together"
                                                              in r for r in absorbed.values()), absorbed
    assert not any(n.startswith("base.") and r.startswith("no effect") for n, r in reasons.items()), reasons


def test_with_nothing_held_out_each_tips_fitting_residuals(dual_arm, capsys):
    """Issue 40, item 7: a tree calibrated with nothing held out reports each tip's fitting
    residuals (mm in report.md), before and after."""
    data = _copy_dataset(dual_arm / "data", dual_arm / "nothing_held_out")
    (data / "calibration.yaml").write_text((data / "calibration.yaml").read_text() + "validation: {holdout: 0}\n")
    report = _calibrate(data, dual_arm / "nothing_held_out_report", capsys)
    assert report["validation"]["by_tip"] is None
    fit = report["fit_by_tip"]
    assert list(fit) == ["left_hand", "right_hand"]
    assert all(entry["after_rms_m"] < entry["before_rms_m"] / 50 for entry in fit.values()), fit
    assert "## Fitting residuals per tip" in (dual_arm / "nothing_held_out_report" / "report.md").read_text()
