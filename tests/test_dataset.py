"""Dataset format: loading, unit conversion and clear errors; the FARO converter."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import SHARED

import fgcal
from fgcal.data.dataset import load_dataset
from fgcal.data.faro import convert_faro

FARO = SHARED / "data" / "irb120_faro"


def _copy(seed_sim: Path, tmp_path: Path) -> Path:
    target = tmp_path / "ds"
    shutil.copytree(seed_sim, target, ignore=shutil.ignore_patterns("truth"))
    return target


def _edit_header(path: Path, **changes) -> None:
    header = yaml.safe_load((path / "dataset.yaml").read_text())
    header.update(changes)
    (path / "dataset.yaml").write_text(yaml.safe_dump(header))


def test_loads_without_truth(seed_sim, tmp_path):
    data = load_dataset(_copy(seed_sim, tmp_path))
    assert data.robot.name == "KUKA KR 125/2"
    assert data.camera is not None and data.camera.width == 1920
    np.testing.assert_allclose(data.camera_mounting[:3, 3], [0, 0, 0.12])


def test_units_are_converted(seed_sim, tmp_path):
    path = _copy(seed_sim, tmp_path)
    reference = load_dataset(path)
    configs = np.genfromtxt(path / "configurations.csv", delimiter=",", dtype=str)
    configs[1:, 1:] = [[repr(float(v) * 180 / np.pi) for v in row] for row in configs[1:, 1:]]
    np.savetxt(path / "configurations.csv", configs, fmt="%s", delimiter=",")
    for name in ("points", "camera_points", "tracker_points"):
        table = np.genfromtxt(path / f"{name}.csv", delimiter=",", dtype=str)
        table[1:, -3:] = [[repr(float(v) * 1000) for v in row] for row in table[1:, -3:]]
        np.savetxt(path / f"{name}.csv", table, fmt="%s", delimiter=",")
    _edit_header(path, units={"length": "mm", "angle": "deg"})
    converted = load_dataset(path)
    np.testing.assert_allclose(converted.q, reference.q, rtol=1e-14)
    for name in ("points", "camera_points", "tracker_points"):
        np.testing.assert_allclose(converted.tables[name].values, reference.tables[name].values, rtol=1e-14)


def _replace_in(path: Path, old: str, new: str, count: int = 1) -> None:
    path.write_text(path.read_text().replace(old, new, count))


@pytest.mark.parametrize(
    ("damage", "where", "message"),
    [
        (lambda p: _edit_header(p, units={"length": "parsec"}), "dataset.yaml", "unknown length unit"),
        (lambda p: _edit_header(p, format="other/2"), "dataset.yaml", "unsupported format"),
        (lambda p: _edit_header(p, robot="ur10e_x"), "dataset.yaml", "robot"),
        (lambda p: _edit_header(p, measured=["laser_scans"]), "dataset.yaml", "unknown measurement kind"),
        (lambda p: (p / "camera_points.csv").unlink(), "camera_points.csv", "file not found"),
        (lambda p: _drop_last_column(p / "configurations.csv"), "configurations.csv", "6 joints"),
        (lambda p: _nan_in(p / "camera_points.csv"), "camera_points.csv", "finite"),
        (
            lambda p: _replace_in(p / "tracker_points.csv", "c0002,", "c9999,"),
            "tracker_points.csv",
            "unknown configuration",
        ),
        (lambda p: _replace_in(p / "pixels.csv", ",A+z_r", ",Z+z_r"), "pixels.csv", "unknown point"),
        (
            lambda p: (p / "configurations.csv").write_text("config,q1,q2,q3,q4,q5,q6\n"),
            "configurations.csv",
            "no configurations",
        ),
    ],
)
def test_bad_datasets_are_clear_errors(seed_sim, tmp_path, damage, where, message):
    path = _copy(seed_sim, tmp_path)
    damage(path)
    with pytest.raises(fgcal.InputError) as info:
        load_dataset(path)
    assert where in str(info.value) and message in str(info.value)


def _drop_last_column(path: Path) -> None:
    """A 5-joint table for a 6-joint robot."""
    path.write_text("".join(line.rsplit(",", 1)[0] + "\n" for line in path.read_text().splitlines()))


def _nan_in(path: Path) -> None:
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[3] = "nan"
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.skipif(not FARO.exists(), reason="../shared/data/irb120_faro is not present")
def test_faro_conversion(tmp_path):
    counts = convert_faro(FARO, tmp_path / "faro")
    data = load_dataset(tmp_path / "faro")
    assert data.robot.name == "ABB IRB 120"
    assert data.q.shape == (1000, 6) and counts["tracker_points"] == 3000
    raw = np.loadtxt(FARO / "measured_joints.txt")
    np.testing.assert_allclose(data.q, np.deg2rad(raw), rtol=1e-15)
    first = np.loadtxt(FARO / "measured_SMR_1.txt")[0] * 1e-3
    np.testing.assert_allclose(data.tables["tracker_points"].values[0], first, rtol=1e-15)
    # Reference reflectors: rows of zeros ("not found") are dropped, nothing else.
    zeros = sum(int(np.all(np.loadtxt(p) == 0, axis=1).sum()) for p in sorted(FARO.glob("measured_base_*.txt")))
    assert counts["tracker_references_dropped_not_found"] == zeros
    assert len(data.tables["tracker_references"]) == 3000 - zeros


def test_faro_converter_errors(tmp_path):
    (tmp_path / "src").mkdir()
    with pytest.raises(fgcal.InputError, match=r"measured_joints\.txt"):
        convert_faro(tmp_path / "src", tmp_path / "out")
    np.savetxt(tmp_path / "src" / "measured_joints.txt", np.zeros((3, 5)))
    with pytest.raises(fgcal.InputError, match=r"no measured_SMR_\*\.txt"):
        convert_faro(tmp_path / "src", tmp_path / "out")
    np.savetxt(tmp_path / "src" / "measured_SMR_1.txt", np.ones((3, 3)))
    with pytest.raises(fgcal.InputError, match=r"column 6 does not exist in .*measured_joints\.txt \(5 columns\)"):
        convert_faro(tmp_path / "src", tmp_path / "out")


def test_csv_errors_name_the_files_own_lines(tmp_path):
    """read_csv's rows carry their lines in the file: leading # comments, blank lines and a quoted
    field across two lines counted, so an error names the line an editor shows (a user trial was
    told "line 3" for line 4 of a file that starts with a comment)."""
    from fgcal.core.errors import InputError
    from fgcal.data.dataset import line_numbers, parse_numbers, read_csv

    path = tmp_path / "t.csv"
    path.write_text('# a comment\n# another\nname,x\na,1\n\n"b\nb",2\nc,oops\n')
    header, body = read_csv(path, ["name", "x"])
    assert line_numbers(body) == (4, 6, 8)
    with pytest.raises(InputError, match="line 8, column x"):
        parse_numbers(path, header, body, ["x"], "length", 1.0)
    path.write_text("# a comment\nname,x\na,1\nb,2,3\n")
    with pytest.raises(InputError, match="line 4"):
        read_csv(path, ["name", "x"])
