"""The simulated seed cell: determinism, measurement model, visibility, deviation range."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SEED_CELL

import fgcal
from fgcal.core.se3 import inverse, transform_points
from fgcal.data.dataset import load_dataset
from fgcal.simulation.cell import load_cell
from fgcal.simulation.simulate import simulate


def _truth(path: Path) -> dict:
    return yaml.safe_load((path / "truth" / "ground_truth.yaml").read_text())


def _noise(path: Path, name: str) -> np.ndarray:
    return np.loadtxt(
        path / "truth" / f"{name}_noise.csv", delimiter=",", skiprows=1, usecols=range(2, 5 if name != "pixels" else 4)
    )


def test_same_seed_same_files_byte_for_byte(seed_sim, tmp_path):
    again = tmp_path / "again"
    simulate(SEED_CELL, again, seed=1)
    files = sorted(p.relative_to(seed_sim) for p in seed_sim.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(again) for p in again.rglob("*") if p.is_file())
    _, mismatch, errors = filecmp.cmpfiles(seed_sim, again, [str(f) for f in files], shallow=False)
    assert not mismatch and not errors


def test_other_seed_other_robot(seed_sim, tmp_path):
    simulate(SEED_CELL, tmp_path / "s2", seed=2)
    assert _truth(seed_sim)["parameters"] != _truth(tmp_path / "s2")["parameters"]


def test_seed_design_shape(seed_sim):
    data = load_dataset(seed_sim)
    # Six sides, three blocks per side, two views per block; four points per image.
    assert data.q.shape == (36, 6)
    assert len(data.tables["camera_points"]) == 144
    per_config = {c: 0 for c in data.configs}
    for c in data.tables["camera_points"].ids["config"]:
        per_config[c] += 1
    assert set(per_config.values()) == {4}
    assert np.all((data.q >= data.robot.limits[:, 0]) & (data.q <= data.robot.limits[:, 1]))


def test_measurements_are_true_prediction_plus_recorded_noise(seed_sim):
    data = load_dataset(seed_sim)
    truth = _truth(seed_sim)
    cell = load_cell(SEED_CELL)
    robot, params = cell.robot, truth["parameters"]
    index = data.config_index(data.tables["camera_points"].ids["config"])
    points = data.tables["points"]
    lookup = {name: i for i, name in enumerate(points.ids["point"])}
    p_F = points.values[[lookup[p] for p in data.tables["camera_points"].ids["point"]]]
    T_C_W = inverse(robot.fk_tool(data.q, params))[index]
    predicted = transform_points(T_C_W, transform_points(cell.fixture_pose, p_F))
    np.testing.assert_allclose(
        data.tables["camera_points"].values, predicted + _noise(seed_sim, "camera_points"), rtol=0, atol=1e-12
    )
    pixels = np.array([cell.camera.project(p[None])[0] for p in predicted])
    np.testing.assert_allclose(data.tables["pixels"].values, pixels + _noise(seed_sim, "pixels"), rtol=0, atol=1e-8)
    # Every point in front of the true camera and inside the image.
    assert np.all(predicted[:, 2] > 0.2)
    assert np.all((pixels >= 0) & (pixels <= [cell.camera.width, cell.camera.height]))

    tracker = data.tables["tracker_points"]
    t_index = data.config_index(tracker.ids["config"])
    targets = np.array([truth["tracker_targets"][t] for t in tracker.ids["target"]])
    T_T_n = inverse(cell.tracker_pose) @ robot.fk(data.q, params)[t_index]
    np.testing.assert_allclose(
        tracker.values, transform_points(T_T_n, targets) + _noise(seed_sim, "tracker_points"), rtol=0, atol=1e-12
    )


def test_noise_has_the_configured_spread(seed_sim):
    assert np.std(_noise(seed_sim, "camera_points")) == pytest.approx(1e-4, rel=0.2)
    assert np.std(_noise(seed_sim, "pixels")) == pytest.approx(0.1, rel=0.2)


def test_seed_one_deviation_in_the_seed_papers_range(seed_sim):
    deviation = _truth(seed_sim)["deviation_before_calibration_m"]
    assert 7e-3 <= deviation["mean"] <= deviation["max"] <= 2e-2


def test_ground_truth_is_not_part_of_the_dataset(seed_sim):
    header = yaml.safe_load((seed_sim / "dataset.yaml").read_text())
    assert not any("truth" in str(v) for v in header["files"].values())


def test_space_filling_design(tmp_path):
    result = simulate(SEED_CELL, tmp_path, seed=3, design="space_filling", n_configurations=24)
    data = load_dataset(tmp_path)
    assert result.n_configurations == 24 and data.q.shape == (24, 6)
    # Spread over joint space: no two configurations nearly equal.
    span = data.robot.limits[:, 1] - data.robot.limits[:, 0]
    x = data.q / span
    gaps = np.linalg.norm(x[:, None] - x[None], axis=-1) + np.eye(len(x))
    assert gaps.min() > 0.02


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda t: t.replace("sides: [+z, -x]}", "sides: [+z, -w]}", 1), "objects[0].sides[1]"),
        (lambda t: t.replace("robot: kuka_kr125_2", "robot: kuka_kr9"), "robot"),
        (
            lambda t: t.replace("units: {length: mm, angle: deg}", "units: {length: furlong, angle: deg}"),
            "units.length",
        ),
        (lambda t: t.replace("fx: 2200,", "fx: .nan,"), "camera.intrinsics.fx"),
        (
            lambda t: t.replace("compliant_joints: [1, 2, 3]", "compliant_joints: [1, 2, 9]"),
            "perturbation.compliant_joints",
        ),
        (lambda t: t.replace("kind: seed", "kind: random"), "design.kind"),
    ],
)
def test_cell_errors_name_file_and_field(tmp_path, edit, field):
    path = tmp_path / "cell.yaml"
    path.write_text(edit(SEED_CELL.read_text()))
    with pytest.raises(fgcal.InputError) as info:
        load_cell(path)
    assert str(path) in str(info.value) and field in str(info.value)
