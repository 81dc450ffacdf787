"""Release per parameter in a stage (issue 40, item 5): {kind, joints} entries, names, and
{release, fix}; listing every joint reproduces the stage of whole kinds exactly."""

from __future__ import annotations

import json

import pytest

from fgcal.commands.cli import main


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    root = tmp_path_factory.mktemp("stages")
    assert main(["simulate", "irb120_tracker", "--out", str(root / "sim"), "--n", "60", "--seed", "2", "-q"]) == 0
    return root


def _estimates(session, name: str, stages: str) -> dict:
    (session / f"{name}.yaml").write_text(f"dataset: sim\nformulation: tracker\nstages: {stages}\n")
    assert main(["calibrate", str(session / f"{name}.yaml"), "--out", str(session / name), "--no-plots", "-q"]) == 0
    report = json.loads((session / name / "report.json").read_text())
    return {n: (p["status"], p["estimate"], p["sigma"]) for n, p in report["parameters"].items()}


def test_every_joint_listed_is_the_whole_kind(session):
    whole = _estimates(session, "whole", "[[theta], [theta, alpha, a]]")
    listed = _estimates(session, "listed", "[[theta], [theta, {kind: alpha, joints: [1-3, 4, '5-6']}, a]]")
    assert listed == whole


def test_some_joints_and_a_fixed_parameter(session):
    some = _estimates(session, "some", "[[theta], {release: [theta, {kind: alpha, joints: [2-3]}, a], fix: [a2]}]")
    released = {n for n, (status, _, _) in some.items() if status == "estimated"}
    assert {"alpha2", "alpha3"} <= released and not {"alpha1", "alpha4", "alpha5", "a2"} & released
    assert "a3" in released


@pytest.mark.parametrize(("stages", "message"), [
    ("[[theta, d60]]", "stages[0]: ABB IRB 120 has no parameter 'd60'"),
    ("[{release: [theta], fix: [a2]}]", "stages[0].fix: a2: the stage does not release it"),
    ("[[theta, {kind: base, joints: [1]}]]", "stages[0][1]"),
    ("[[theta, {kind: alpha, joints: [3-1]}]]", "stages[0][1].joints"),
    ("[{release: [theta], keep: [a2]}]", "stages[0]"),
    ("[[theta, {kind: alpha, joints: [1-8]}]]", "{kind: alpha, joints}: joint 7 is not one of ABB IRB 120's 6"),
    ("[[theta, {kind: kc, joints: [2]}]]", "{kind: kc, joints}: none of the joints listed has a parameter kc"),
])  # fmt: skip
def test_stages_that_cannot_be_are_refused(session, stages, message, capsys):
    (session / "bad.yaml").write_text(f"dataset: sim\nformulation: tracker\nstages: {stages}\n")
    assert main(["calibrate", str(session / "bad.yaml"), "--out", str(session / "bad"), "--no-plots"]) == 2
    assert message in capsys.readouterr().err


def test_a_trees_default_compliances_are_every_loaded_joint():
    """Issue 40, item 4: on a tree the default compliant joints are every revolute joint that
    carries a mass (the seed's 1-3 left a 20-joint tree its torso's only); a serial arm keeps 1-3."""
    import fgcal
    from fgcal.calibration.problem import compliant_joints

    tree = fgcal.load_robot("dual_arm_torso")
    assert compliant_joints(tree, None) == tuple(range(1, tree.n_links + 1))
    assert compliant_joints(fgcal.load_robot("abb_irb120"), None) == (1, 2, 3)
    assert compliant_joints(tree, (2, 3)) == (2, 3)


def test_a_kind_on_joints_of_a_mixed_tree_releases_where_the_joint_has_it():
    """{kind, joints} over a robot whose joints differ in kinds (DH rows and joints given by their
    origin, which have no alpha): the kind where a listed joint has it, as the whole kind does;
    kc on the joint that has it. A joint beyond the robot stays refused (above)."""
    from fgcal.calibration.schema import _release_items
    from fgcal.calibration.solve import selects

    stage = _release_items(["theta", {"kind": "alpha", "joints": ["1-10"]}, {"kind": "kc", "joints": [3]}], "[0]")
    assert selects(stage, "alpha9") and selects(stage, "kc3") and not selects(stage, "kc4")
    assert not selects(stage, "alpha11") and selects(stage, "theta9")
