"""The seams of the calibration pipeline: every registered formulation through the whole of it
on a small simulated cell (calibrate, held-out score, its prediction, estimates.yaml, report),
the default solve against an independent NumPy Gauss-Newton on the same residuals, and the
covariance against GTSAM's Marginals."""

from __future__ import annotations

import json
from pathlib import Path

import gtsam
import numpy as np
import pytest
import yaml
from conftest import REPO

import fgcal
from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.formulations import REGISTRY
from fgcal.calibration.results import primary_score
from fgcal.calibration.run import calibrate
from fgcal.calibration.scoring import score_with_truth
from fgcal.reports.calibration import write_report
from fgcal.reports.estimates import load_estimates
from fgcal.simulation.simulate import simulate

CELLS = REPO / "datasets" / "cells"
# Per formulation: a bundled cell, cut down so that simulating and calibrating take seconds,
# and what its engineer declares.
SELF_CONTAINED = {
    "contact": {"self_contacts": 260, "plane_contacts": 70, "gauge": {"readings": 280},
                "hold": {"joints": [1, 2, 3], "at": [0, 0, 0]}},
    "self_observation": {"views": 150},
    "noise": {"pixel_sigma_px": 0.05},
    "perturbation": {"length": 0, "compliance": [0, 0], "distortion": 0, "mass_scale": 0},
}  # fmt: skip
FAST = {
    "pairs": ("kr125_seed", {}, {}),
    "projection": ("kr125_seed", {}, {}),
    "tracker": ("irb120_tracker", {"design": {"kind": "space_filling", "n_configurations": 40}},
                {"noise": {"tracker_sigma": 1.5e-5}}),
    "poses": ("irb120_tracker6d", {"design": {"kind": "space_filling", "n_configurations": 40}},
              {"noise": {"pose_sigma": 1.5e-5, "pose_angle_sigma": 8.7e-5}}),
    "distances": ("irb120_ballbar", {"ballbar": {"readings_per_pivot": 70}}, {"noise": {"distance_sigma": 1e-6}}),
    "touch": ("seven_axis_touch", {"touch": {"touches_per_point": 16}},
              {"compliant_joints": [2, 4], "noise": {"touch_sigma": 5e-6, "spacing_sigma": 3e-6}}),
    "static_camera": ("irb120_static_camera", {"design": {"n_configurations": 40}}, {"noise": {"pixel_sigma_px": 0.1}}),
    # A robot measuring itself: one dataset for the four (simulated once). Contacts alone have no
    # scale but a ball's radius, and self-contact, the hands' gauge and the torso's cameras cannot
    # see the torso: here the lengths are the drawing's and the torso is held (docs/model.md, "A
    # robot measuring itself").
    "self_contact": ("dual_arm_selfcontained", SELF_CONTAINED, {"model": "DH"}),
    "planes": ("dual_arm_selfcontained", SELF_CONTAINED, {"model": "DH"}),
    "tip_gauge": ("dual_arm_selfcontained", SELF_CONTAINED, {"model": "DH"}),
    "self_observation": ("dual_arm_selfcontained", SELF_CONTAINED, {"model": "DH"}),
}  # fmt: skip


# The fixed parameters a formulation's truth score may see and its data cannot
# (Prediction.assumes): contacts and planes have no length but a ball's radius, so the analysis
# fixes the arms' lengths that carry the scale; each torso camera sees only the board on its
# own arm, so where each arm hangs from the torso (its first row) is taken by that camera's
# mounting, while the truth score of both hands in W sees it. Where one of them is off in the
# simulated truth, the prediction does not cover the truth score and says so (self_observation:
# 2.1x on seed 2 of this cell, 26x on seed 3, before the prediction named them).
ARM_LENGTHS = {f"{kind}{joint}" for kind in ("d", "a") for joint in range(5, 19)}
BLIND_SPOTS = {
    "self_contact": ARM_LENGTHS,
    "planes": ARM_LENGTHS,
    "self_observation": {f"{kind}{joint}" for kind in ("theta", "d", "a", "alpha") for joint in (5, 12)},
}


def _merge(base: dict, edits: dict) -> dict:
    out = dict(base)
    for key, value in edits.items():
        out[key] = _merge(base.get(key, {}), value) if isinstance(value, dict) else value
    return out


@pytest.fixture(scope="module")
def fast_cells(tmp_path_factory) -> dict[str, Path]:
    out, simulated = {}, {}
    for name, (cell, edits, _) in FAST.items():
        doc = _merge(yaml.safe_load((CELLS / f"{cell}.yaml").read_text()), edits)
        key = yaml.safe_dump(doc)
        same = simulated.get(key)
        if same is not None:  # one simulation serves the formulations that read its tables
            out[name] = same
            continue
        root = tmp_path_factory.mktemp(name)
        robot = CELLS / str(doc["robot"])
        if robot.suffix in (".urdf", ".yaml"):  # a robot file beside the cell
            doc["robot"] = str(robot)
        (root / "cell.yaml").write_text(yaml.safe_dump(doc))
        simulate(root / "cell.yaml", root / "data", seed=2)
        out[name] = simulated[key] = root / "data"
    return out


def test_every_registered_formulation_has_a_seam_test():
    assert set(FAST) == set(REGISTRY)


@pytest.mark.parametrize("name", list(FAST))
def test_each_formulation_through_the_whole_pipeline(fast_cells, name, tmp_path):
    """Calibrated without the truth, then scored with it: the held-out score improves on the
    nominal model and lies within 2x of its prediction, both ways; every auxiliary unknown is
    written to estimates.yaml with sigmas and reads back; report.json is strict JSON and agrees
    with the result."""
    formulation = REGISTRY[name]()
    config = CalibrationConfig.defaults(fast_cells[name], formulation=name, **FAST[name][2])
    measured = calibrate(config)
    assert measured.problem.formulation.name == name and measured.truth is None
    score, after = primary_score(measured.validation, "after")
    _, before = primary_score(measured.validation, "before")
    assert score == formulation.score and after.rms < before.rms / 3
    assert 0.5 <= after.rms / measured.prediction.rms <= 2.0, (after.rms, measured.prediction)

    scored = score_with_truth(measured)
    assert scored.truth is not None and scored.measured is measured.validation
    truth_before, truth_after = (scored.validation[k]["tool_point"].rms for k in ("before", "after"))
    assert truth_after < truth_before / 10
    blind = {spot.name for spot in scored.prediction.assumes}
    assert blind <= BLIND_SPOTS.get(name, set()), blind
    names = scored.problem.robot.parameter_names
    true_params = scored.problem.formulation.true_state(scored.problem, scored.truth)[1].params
    off = [n for n in blind if abs(true_params[names.index(n)] - scored.state.params[names.index(n)]) > 1e-12]
    if not off:  # else the prediction says it does not cover what the truth score sees
        assert 0.5 <= truth_after / scored.prediction.rms <= 2.0, (truth_after, scored.prediction)

    doc = write_report(scored, tmp_path)
    back = load_estimates(tmp_path / "estimates.yaml")
    raw = yaml.safe_load((tmp_path / "estimates.yaml").read_text())
    assert set(scored.state.aux) <= set(back)
    for unknown, aux in scored.state.aux.items():
        assert raw[unknown] is not None
        if aux.kind == "pose3":
            np.testing.assert_allclose(back[unknown], aux.value, atol=1e-12)
            assert min(raw[unknown]["sigma"]["translation"]) > 0
        elif aux.kind == "points":
            for label, point in zip(aux.labels, aux.value, strict=True):
                np.testing.assert_allclose(back[unknown][label], point, atol=1e-15)
                assert min(raw[unknown][label]["sigma"]) > 0
    report = json.loads((tmp_path / "report.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert report["formulation"] == name == doc["formulation"]
    assert report["validation"]["after"]["position_error_m"]["rms"] == pytest.approx(truth_after, rel=1e-12)
    assert report["validation"]["predicted_position_sigma_m"]["rms"] == pytest.approx(scored.prediction.rms)
    assert "## Held-out error" in (tmp_path / "report.md").read_text()
    # The calibrated robot file carries the tool the calibration estimated on the flange (a
    # probe, a ball, a 6D probe's frame; issue 22, item 9), or its own calibrated tool.
    robot, params = scored.problem.robot, scored.parameters
    q = scored.problem.dataset.q[:4]
    tool = formulation.tool_frame(scored.state)
    expected = robot.fk_tool(q, params) if tool is None else robot.fk(q, params) @ tool
    np.testing.assert_allclose(fgcal.load_robot(tmp_path / "calibrated_robot.yaml").fk_tool(q), expected, atol=1e-12)
    assert (tool is not None) == (name in ("touch", "distances", "poses"))


def test_the_default_solve_equals_an_independent_gauss_newton(fast_cells):
    """The seed design (36 images, pairs): GTSAM's Levenberg-Marquardt on the factor graph and
    a bare NumPy Gauss-Newton on the same residuals, written apart (fgcal.bench.suite.PairResiduals:
    the point-pair contrasts and length bounds from the kinematics alone), stage by stage from
    the same start, reach the same parameters to a thousandth of their sigma."""
    from fgcal.bench.suite import fgcal_solve, numpy_gauss_newton
    from fgcal.calibration.run import build_problem
    from fgcal.data.dataset import load_dataset

    config = CalibrationConfig.defaults(fast_cells["pairs"])
    result = calibrate(config)
    problem = build_problem(load_dataset(fast_cells["pairs"]), config)
    identifiable = result.identifiability.identifiable
    mine = fgcal_solve(problem, config.stages, identifiable)
    theirs = numpy_gauss_newton(problem, config.stages, identifiable)
    names = problem.robot.parameter_names
    index = [names.index(n) for n in result.released]
    sigma = np.array([result.sigmas[n] for n in result.released])
    np.testing.assert_allclose(mine, result.state.params, rtol=0, atol=1e-12)
    assert np.max(np.abs(mine[index] - theirs[index]) / sigma) < 1e-3
    untouched = np.setdiff1d(np.arange(len(names)), index)
    np.testing.assert_array_equal(mine[untouched], theirs[untouched])


def test_the_covariance_equals_gtsams_marginals(fast_cells):
    """Where gtsam.Marginals (Cholesky) works, the QR covariance of the last stage equals it to
    1e-9 relative, auxiliary unknowns included (a tracker and its reflectors)."""
    from fgcal.calibration.covariance import joint_covariance
    from fgcal.calibration.graph import build_graph

    result = calibrate(CalibrationConfig.defaults(fast_cells["tracker"], formulation="tracker"))
    stage = build_graph(result.problem, result.released, result.state)
    covariance = joint_covariance(stage, stage.values)
    keys = gtsam.KeyVector([key for key, _ in stage.dims.values()])
    marginal = gtsam.Marginals(stage.graph, stage.values).jointMarginalCovariance(keys).fullMatrix()
    scale = np.sqrt(np.outer(np.diag(marginal), np.diag(marginal)))
    assert np.max(np.abs(covariance.matrix - marginal) / scale) < 1e-9
    assert list(covariance.offsets) == ["P", "tracker", "tool_points"]
