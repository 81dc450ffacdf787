"""Bad input, table-driven: each case damages a copy of a small simulated dataset (or its
calibration config) and runs ``fgcal calibrate``. A damaged input must give exit status 2 and
one line ``fgcal: error: <file>: <field>: <problem>`` naming the file and the field, without a
traceback, within a bounded time; a legitimate oddity must calibrate normally."""

from __future__ import annotations

import json
import shutil
import signal
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

from fgcal.commands.cli import main

SECONDS = 60  # far above any case here; a hang fails instead of blocking the suite


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> Path:
    from conftest import SEED_CELL

    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("bad_input_source")
    simulate(SEED_CELL, out, seed=3)
    return out


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines(keepends=True)


def set_cell(table: str, row: int, column: str, text: str) -> Callable[[Path], None]:
    """Replace one cell (row 1 is the first data row) of a table."""

    def apply(data: Path) -> None:
        lines = _lines(data / table)
        header = lines[0].strip().split(",")
        cells = lines[row].rstrip("\r\n").split(",")
        cells[header.index(column)] = text
        lines[row] = ",".join(cells) + "\n"
        (data / table).write_text("".join(lines), encoding="utf-8")

    return apply


def set_header(key: str, value) -> Callable[[Path], None]:
    """Set ``dataset.yaml`` field ``key`` (dotted) to ``value``."""

    def apply(data: Path) -> None:
        doc = yaml.safe_load((data / "dataset.yaml").read_text(encoding="utf-8"))
        *parents, last = key.split(".")
        node = doc
        for part in parents:
            node = node[part]
        node[last] = value
        (data / "dataset.yaml").write_text(yaml.safe_dump(doc), encoding="utf-8")

    return apply


def rewrite(table: str, change: Callable[[str], str]) -> Callable[[Path], None]:
    def apply(data: Path) -> None:
        path = data / table
        path.write_bytes(change(path.read_text(encoding="utf-8")).encode("utf-8"))

    return apply


def _outside(data: Path) -> None:
    shutil.copy(data / "camera_points.csv", data.parent / "elsewhere.csv")
    set_header("files.camera_points", "../elsewhere.csv")(data)


def _absolute(data: Path) -> None:
    shutil.copy(data / "camera_points.csv", data.parent / "elsewhere.csv")
    set_header("files.camera_points", str((data.parent / "elsewhere.csv").resolve()))(data)


# (case id, damage to the dataset, config overrides, file named, field named)
BAD = [
    # issue 13, defect 1: a tracker value of 1e300 hung the Kabsch initialisation
    (
        "tracker_1e300",
        set_cell("tracker_points.csv", 3, "y", "1e300"),
        {"formulation": "tracker"},
        "tracker_points.csv",
        "line 4, column y",
    ),
    # defect 2: a target not declared in dataset.yaml: KeyError traceback
    (
        "tracker_undeclared_target",
        set_cell("tracker_points.csv", 2, "target", "t9"),
        {"formulation": "tracker"},
        "tracker_points.csv",
        "target",
    ),
    # defect 3: a camera point of 1e300 (GTSAM's "Indeterminate linear system"); a pixel of 1e300
    ("camera_point_1e300", set_cell("camera_points.csv", 5, "x", "1e300"), {}, "camera_points.csv", "column x"),
    ("pixel_1e300", set_cell("pixels.csv", 5, "u", "1e300"), {"formulation": "projection"}, "pixels.csv", "column u"),
    # defect 4: Python's float() accepts underscores and full-width digits
    ("underscore_digit", set_cell("camera_points.csv", 2, "z", "0_1"), {}, "camera_points.csv", "column z"),
    ("underscore_thousands", set_cell("configurations.csv", 2, "q2", "1_000"), {}, "configurations.csv", "column q2"),
    ("full_width_digits", set_cell("camera_points.csv", 2, "y", "\uff11.\uff15"), {}, "camera_points.csv", "column y"),
    # defect 5: table paths outside the dataset folder
    ("table_outside_dataset", _outside, {}, "dataset.yaml", "files.camera_points"),
    ("table_absolute_path", _absolute, {}, "dataset.yaml", "files.camera_points"),
    # neighbours of the defects
    ("joint_angle_1e300", set_cell("configurations.csv", 1, "q3", "1e300"), {}, "configurations.csv", "column q3"),
    ("nan_in_points", set_cell("points.csv", 1, "x", "nan"), {}, "points.csv", "column x"),
    (
        "inf_in_tracker",
        set_cell("tracker_points.csv", 1, "z", "-inf"),
        {"formulation": "tracker"},
        "tracker_points.csv",
        "column z",
    ),
    ("hex_number", set_cell("camera_points.csv", 1, "x", "0x10"), {}, "camera_points.csv", "column x"),
]


@pytest.fixture
def alarm():
    def timeout(_signum, _frame):
        raise TimeoutError(f"no answer within {SECONDS} s")

    previous = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(SECONDS)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


def _calibrate(small_dataset: Path, tmp_path: Path, damage, overrides: dict) -> tuple[int, Path]:
    data = tmp_path / "data"
    shutil.copytree(small_dataset, data)
    if damage is not None:
        damage(data)
    config = tmp_path / "calibration.yaml"
    config.write_text(yaml.safe_dump({"dataset": "data", **overrides}), encoding="utf-8")
    return main(["calibrate", str(config), "--out", str(tmp_path / "out"), "--no-plots"]), config


@pytest.mark.parametrize(("damage", "overrides", "file", "field"), [c[1:] for c in BAD], ids=[c[0] for c in BAD])
def test_bad_input_is_one_clear_line(small_dataset, tmp_path, capsys, alarm, damage, overrides, file, field):
    status, _ = _calibrate(small_dataset, tmp_path, damage, overrides)
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error, error
    assert file in error and field in error, error
    assert not (tmp_path / "out" / "calibrated_robot.yaml").exists()


def _bom(data: Path) -> None:
    rewrite("camera_points.csv", lambda text: "\ufeff" + text)(data)


def _crlf_and_blank_lines(data: Path) -> None:
    rewrite("camera_points.csv", lambda text: text.replace("\n", "\r\n") + "\r\n\r\n")(data)


ODD = [
    ("byte_order_mark", _bom, {}),
    ("crlf_and_trailing_blank_lines", _crlf_and_blank_lines, {}),
    # defect 11: YAML 1.1 reads 1e-4 (no dot) as text
    ("yaml_float_without_dot", None, {"noise": {"camera_point_sigma": "1e-4"}}),
]


@pytest.mark.parametrize(("damage", "overrides"), [c[1:] for c in ODD], ids=[c[0] for c in ODD])
def test_legitimate_oddities_calibrate(small_dataset, tmp_path, capsys, alarm, damage, overrides):
    status, _ = _calibrate(small_dataset, tmp_path, damage, overrides)
    assert status == 0, capsys.readouterr().err
    report = json.loads((tmp_path / "out" / "report.json").read_text(encoding="utf-8"))
    assert report["n_residuals"] > 0


def test_yaml_float_without_dot_is_read_as_the_number(tmp_path):
    from fgcal.calibration.config import load_config

    config = tmp_path / "c.yaml"
    config.write_text("dataset: x\nnoise: {camera_point_sigma: 1e-4}\n", encoding="utf-8")
    assert load_config(config).noise.camera_point_m == 1e-4


def _reject_constant(name: str):
    raise ValueError(f"not strict JSON: {name}")


def test_report_json_is_strict_without_a_held_out_set(small_dataset, tmp_path, capsys, alarm):
    # defect 10: holdout 0 wrote NaN into report.json
    status, _ = _calibrate(small_dataset, tmp_path, None, {"validation": {"holdout": 0}})
    assert status == 0, capsys.readouterr().err
    text = (tmp_path / "out" / "report.json").read_text(encoding="utf-8")
    json.loads(text, parse_constant=_reject_constant)


def test_an_unreachable_cell_fails_fast_naming_the_cell(tmp_path, capsys, alarm):
    # Issue 13, defect 11: an unreachable design searched for 84 s, then failed without naming
    # the file or the field.
    import time

    from conftest import SEED_CELL

    cell = tmp_path / "far.yaml"
    text = SEED_CELL.read_text(encoding="utf-8").replace("fixture: {xyz: [0, 0, 0]", "fixture: {xyz: [20000, 0, 0]")
    cell.write_text(text, encoding="utf-8")
    started = time.monotonic()
    status = main(["simulate", str(cell), "--out", str(tmp_path / "out"), "--seed", "1"])
    error = capsys.readouterr().err.strip()
    assert status == 2 and error.startswith("fgcal: error: ") and "\n" not in error, error
    assert "far.yaml" in error and "objects" in error, error
    assert time.monotonic() - started < 20


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("format: fgcal-estimates/9\ncamera_mounting: {pose: {xyz: [0, 0, 0], rpy: [0, 0, 0]}}\n", "format"),
        ("format: fgcal-estimates/1\ncamera_mounting: {pose: {xyz: [0, 0], rpy: [0, 0, 0]}}\n", "xyz"),
        ("format: fgcal-estimates/1\n", "camera_mounting"),
        ("format: fgcal-estimates/1\ncamera_mounting: {pose: {xyz: [0, 0, 0], rpy: [0, 0, 0]}}\nbonus: 1\n", "bonus"),
        ("format: [\n", "malformed YAML"),
    ],
    ids=["format", "short_xyz", "no_mounting", "unknown_key", "malformed"],
)
def test_a_damaged_estimates_file_names_the_field(tmp_path, text, field):
    from fgcal.core.errors import InputError
    from fgcal.reports.estimates import load_estimates

    path = tmp_path / "estimates.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=field):
        load_estimates(path)
