"""Robot library and robot file schema: every error names the file and the field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import random_parameters

import fgcal
from fgcal.model.robot_io import bundled_robots, robots_dir


def test_bundled_library():
    assert {"kuka_kr125_2", "abb_irb120", "ur10e", "puma560", "seven_axis"} <= set(bundled_robots())
    for name in bundled_robots():
        robot = fgcal.load_robot(name)
        assert robot.n_joints == {
            "seven_axis": 7,
            "positioner_2axis": 2,
            "dual_arm_torso": 17,
            "humanoid_upper_body": 17,
            "irb120_positioner": 8,
        }.get(name, 6)
        assert robot.source.strip(), f"{name} must name its source"
        assert np.all(robot.limits[:, 0] < robot.limits[:, 1])


def test_kuka_matches_spec_table():
    robot = fgcal.load_robot("kuka_kr125_2")
    np.testing.assert_allclose(robot.dh[:, 2], [0.41, 1.0, 0.045, 0, 0, 0])
    np.testing.assert_allclose(robot.dh[:, 1], [0.865, 0, 0, -1.0, 0, -0.21])
    np.testing.assert_allclose(np.rad2deg(robot.dh[:, 3]), [-90, 0, 90, -90, 90, 180])
    np.testing.assert_allclose(np.rad2deg(robot.dh[:, 0]), [0, 0, -90, 0, 0, 180])
    np.testing.assert_array_equal(robot.directions, [-1, 1, 1, 1, 1, 1])
    np.testing.assert_allclose(np.rad2deg(robot.limits[1]), [-130, 3])
    assert 600 < robot.masses.sum() < 1000  # documented estimate: the moving arm of a ~1 t robot


def _robot_doc() -> dict:
    return yaml.safe_load((robots_dir() / "puma560.yaml").read_text())


def _write(tmp_path: Path, doc: object, text: str | None = None) -> Path:
    path = tmp_path / "robot.yaml"
    path.write_text(text if text is not None else yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize(
    ("mutate", "field", "message"),
    [
        (lambda d: d.pop("joints"), "joints", "missing"),
        (lambda d: d["joints"][2].update(alpha=float("nan")), "joints[2].alpha", "finite"),
        (lambda d: d["joints"][1].update(d="abc"), "joints[1].d", "number"),
        (lambda d: d["joints"][0].update(direction=2), "joints[0].direction", "+1 or -1"),
        (lambda d: d["joints"][3].update(limits=[10, -10]), "joints[3].limits", "lower limit"),
        (lambda d: d["joints"][3].update(limits=[10]), "joints[3].limits", "2 numbers"),
        (lambda d: d["joints"][4].update(alfa=1), "joints[4].alfa", "unknown field"),
        (lambda d: d.update(units={"length": "inch"}), "units.length", "unknown length unit"),
        (lambda d: d.update(units={"angle": "grad"}), "units.angle", "unknown angle unit"),
        (lambda d: d.update(parameters={"theta7": 1.0}), "parameters.theta7", "unknown parameter"),
        (lambda d: d["joints"][5].update(mass=-1), "joints[5].mass", ">= 0"),
        (lambda d: d.pop("source"), "source", "missing"),
    ],
)
def test_schema_errors_name_file_and_field(tmp_path, mutate, field, message):
    doc = _robot_doc()
    mutate(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(fgcal.InputError) as info:
        fgcal.load_robot(path)
    text = str(info.value)
    assert str(path) in text and field in text and message in text


def test_malformed_yaml_names_the_line(tmp_path):
    path = _write(tmp_path, None, "name: x\njoints: [\n  - {a: 1\n")
    with pytest.raises(fgcal.InputError, match=r"malformed YAML: line \d+"):
        fgcal.load_robot(path)


def test_unknown_robot_name_lists_the_bundled_ones():
    with pytest.raises(fgcal.InputError, match="kuka_kr125_2"):
        fgcal.load_robot("kuka_kr1000")


def test_units_are_converted_at_load(tmp_path):
    doc = _robot_doc()
    for joint in doc["joints"]:
        joint["d"] *= 1000.0
        joint["a"] *= 1000.0
        joint["com"] = [1000.0 * c for c in joint["com"]]
    doc["units"] = {"length": "mm", "angle": "deg"}
    converted = fgcal.load_robot(_write(tmp_path, doc))
    original = fgcal.load_robot("puma560")
    q = np.random.default_rng(0).uniform(-1, 1, (4, 6))
    np.testing.assert_allclose(converted.fk(q), original.fk(q), atol=1e-12)


def test_save_and_reload_reproduces_a_calibrated_robot(tmp_path):
    robot = fgcal.load_robot("kuka_kr125_2")
    params = random_parameters(robot, np.random.default_rng(2))
    fgcal.save_robot(tmp_path / "calibrated.yaml", robot, params)
    reloaded = fgcal.load_robot(tmp_path / "calibrated.yaml")
    q = np.random.default_rng(3).uniform(-1, 1, (5, 6))
    np.testing.assert_allclose(reloaded.fk(q), robot.fk(q, params), atol=1e-12)
    np.testing.assert_allclose(reloaded.fk_tool(q), robot.fk_tool(q, params), atol=1e-12)
