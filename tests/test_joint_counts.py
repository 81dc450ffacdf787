"""Issue 12, item 3: any joint count works with default settings (a 2-axis positioner failed:
compliant_joints [1, 2, 3] named a joint it does not have)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.run import calibrate
from fgcal.model.robot_io import load_robot

POSITIONER = {
    "name": "Two-axis positioner",
    "source": "test fixture: a tilt-and-turn table",
    "units": {"length": "mm", "angle": "deg"},
    "joints": [
        {"d": 400, "a": 0, "alpha": -90, "theta": 0, "limits": [-120, 120], "mass": 40, "com": [0, 0, 0]},
        {"d": 150, "a": 0, "alpha": 0, "theta": 0, "limits": [-360, 360], "mass": 15, "com": [0, 0, 50]},
    ],
}


def _tracker_dataset(folder, robot_file, rng):
    """Reflectors on the table measured by a tracker at 80 configurations (test-side truth)."""
    robot = load_robot(robot_file)
    true = robot.nominal_parameters()
    for name in true:
        if (name[0] in "da" and name[1:].isdigit()) or name.startswith(("theta", "alpha")):
            true[name] += rng.normal(0, 0.002)
    q = rng.uniform(robot.limits[:, 0] * 0.9, robot.limits[:, 1] * 0.9, (80, 2))
    targets = np.array([[0.2, 0.0, 0.05], [-0.1, 0.17, 0.05], [-0.1, -0.17, 0.05]])
    flange = robot.fk(q, true)
    rows = ["config,target,x,y,z"]
    for j, T in enumerate(flange):
        for t, s in enumerate(targets):
            p = T[:3, :3] @ s + T[:3, 3] + rng.normal(0, 1e-5, 3)
            rows.append(f"c{j:03d},t{t + 1}," + ",".join(repr(float(v)) for v in p))
    (folder / "tracker_points.csv").write_text("\n".join(rows) + "\n")
    lines = ["config,q1,q2"] + [f"c{j:03d},{a!r},{b!r}" for j, (a, b) in enumerate(q.tolist())]
    (folder / "configurations.csv").write_text("\n".join(lines) + "\n")
    header = {
        "format": "fgcal-dataset/1",
        "robot": robot_file.name,
        "units": {"length": "m", "angle": "rad"},
        "measured": ["tracker_points"],
        "files": {"configurations": "configurations.csv", "tracker_points": "tracker_points.csv"},
        "tracker": {"targets": ["t1", "t2", "t3"]},
        "source": "test",
    }
    (folder / "dataset.yaml").write_text(yaml.safe_dump(header))


@pytest.mark.parametrize("model", ["DH", "DH,s,e"])
def test_a_two_axis_positioner_calibrates_with_default_settings(tmp_path, model):
    robot_file = tmp_path / "positioner.yaml"
    robot_file.write_text(yaml.safe_dump(POSITIONER))
    _tracker_dataset(tmp_path, robot_file, np.random.default_rng(12))
    result = calibrate(CalibrationConfig.defaults(tmp_path, formulation="tracker", model=model))
    after = result.validation["after"]["tool_point"]
    before = result.validation["before"]["tool_point"]
    assert after.rms < 1e-4 and after.rms < before.rms / 10, (before.rms, after.rms)
    assert all(not n.startswith("k") or int(n[2:]) <= 2 for n in result.problem.candidates)
