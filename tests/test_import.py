"""The generic importer (fgcal import-csv): instrument and controller exports in their own
layouts, delimiters, decimal marks, units and rotation conventions, read back to the very
values of the simulated dataset they were written from; bad mappings and bad cells refused
with the file, line and field (issue 12)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO
from scipy.spatial.transform import Rotation

from fgcal.core.errors import InputError
from fgcal.data.csv_import import import_tables
from fgcal.data.dataset import load_dataset
from fgcal.simulation.simulate import simulate

CELLS = REPO / "datasets" / "cells"


@pytest.fixture(scope="module")
def probe_session(tmp_path_factory) -> Path:
    """A simulated 6D-probe session (tracker points and poses), SI."""
    out = tmp_path_factory.mktemp("probe")
    simulate(CELLS / "irb120_tracker6d.yaml", out, seed=1)
    return out


def _exports(session: Path, folder: Path) -> dict:
    """Write the session as three vendors would, and the mapping that reads them.

    - controller log: two preamble lines, ';' and decimal commas, degrees, rows in reverse order;
    - tracker: one row per reflector reading in mm, plus a reading of a reflector not found;
    - 6D probe: whitespace, no header, position in m, orientation as intrinsic ZYX Euler angles
      in degrees (columns in the sequence's order: Rz, Ry, Rx)."""
    data = load_dataset(session)
    folder.mkdir(exist_ok=True)
    ids = [f"P{i + 1:03d}" for i in range(len(data.configs))]
    lines = ["KRC log export", "2026-11-23 robot 1", "Pose;A1;A2;A3;A4;A5;A6"]
    for pose_id, q in reversed(list(zip(ids, data.q, strict=True))):
        lines.append(";".join([pose_id, *(repr(float(v)).replace(".", ",") for v in np.rad2deg(q))]))
    (folder / "controller.csv").write_text("\n".join(lines) + "\n")

    points = data.tables["tracker_points"]
    rows = ["Pose,Name,X [mm],Y [mm],Z [mm]"]
    for config, target, xyz in zip(points.ids["config"], points.ids["target"], points.values, strict=True):
        rows.append(",".join([ids[list(data.configs).index(config)], target, *(repr(float(v)) for v in xyz * 1e3)]))
    rows.append(f"{ids[0]},t9,,,")  # not found
    (folder / "tracker.csv").write_text("\n".join(rows) + "\n")

    poses = data.tables["tracker_poses"]
    rows = []
    for config, value in zip(poses.ids["config"], poses.values, strict=True):
        qw, qx, qy, qz = value[3:]
        rz, ry, rx = Rotation.from_quat([qx, qy, qz, qw]).as_euler("ZYX", degrees=True)
        rows.append(
            " ".join([ids[list(data.configs).index(config)], *(repr(float(v)) for v in (*value[:3], rz, ry, rx))])
        )
    (folder / "probe.txt").write_text("\n".join(rows) + "\n")
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "units": {"length": "mm", "angle": "deg"},
        "configurations": {
            "file": "controller.csv",
            "skip_rows": 2,
            "decimal": ",",
            "config": "Pose",
            "joints": ["A1", "A2", "A3", "A4", "A5", "A6"],
        },
        "tracker_points": {
            "file": "tracker.csv",
            "config": "Pose",
            "target": "Name",
            "xyz": ["X [mm]", "Y [mm]", "Z [mm]"],
        },
        "tracker_poses": {
            "file": "probe.txt",
            "header": False,
            "units": {"length": "m"},
            "config": 1,
            "xyz": [2, 3, 4],
            "euler": {"columns": [5, 6, 7], "sequence": "ZYX"},
        },
        "payload": {"mass": 0.6, "com": [0, 0, 40]},
        "source": "three exports of one session",
    }
    (folder / "mapping.yaml").write_text(yaml.safe_dump(mapping, sort_keys=False))
    return mapping


def test_exports_read_back_to_the_session(probe_session, tmp_path):
    """Every value of the session comes back through the vendors' layouts: joint angles,
    reflector positions (mm), probe positions (m) and orientations (Euler angles to
    quaternions, up to the quaternion's sign); the reflector not found is dropped and counted."""
    _exports(probe_session, tmp_path / "exports")
    counts = import_tables(tmp_path / "exports" / "mapping.yaml", tmp_path / "dataset")
    original, imported = load_dataset(probe_session), load_dataset(tmp_path / "dataset")
    n = len(original.configs)
    assert counts == {
        "configurations": n,
        "tracker_points": n,
        "tracker_points_dropped_not_found": 1,
        "tracker_poses": n,
        "tracker_poses_dropped_not_found": 0,
    }
    # The controller log ran backwards: configuration P001 is the session's first.
    order = np.argsort(imported.configs)
    np.testing.assert_allclose(imported.q[order], original.q, rtol=0, atol=1e-13)
    for name in ("tracker_points", "tracker_poses"):
        got, want = imported.tables[name], original.tables[name]
        assert list(got.ids["config"]) == [f"P{i + 1:03d}" for i in original.config_index(want.ids["config"])]
        np.testing.assert_allclose(got.values[:, :3], want.values[:, :3], rtol=0, atol=1e-12)
    q_got, q_want = imported.tables["tracker_poses"].values[:, 3:], original.tables["tracker_poses"].values[:, 3:]
    np.testing.assert_allclose(np.abs(np.sum(q_got * q_want, axis=1)), 1.0, atol=1e-12)
    assert imported.header["tracker"] == {"targets": ["t1"]}
    np.testing.assert_allclose(imported.robot.payload_com, [0, 0, 0.04])


def test_ballbar_export_by_row(tmp_path):
    """A ballbar log without configuration ids: row i is configuration i, the pivot a column."""
    session = tmp_path / "session"
    simulate(CELLS / "irb120_ballbar.yaml", session, seed=1)
    data = load_dataset(session)
    np.savetxt(tmp_path / "joints.txt", data.q)
    table = data.tables["distances"]
    rows = [f"{p}\t{float(d) * 1e3!r}" for p, d in zip(table.ids["pivot"], table.values[:, 0], strict=True)]
    (tmp_path / "bar.tsv").write_text("pivot\tlength_mm\n" + "\n".join(rows) + "\n")
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "units": {"length": "mm", "angle": "rad"},
        "configurations": {"file": "joints.txt", "header": False, "joints": [1, 2, 3, 4, 5, 6]},
        "distances": {"file": "bar.tsv", "pivot": "pivot", "distance": "length_mm"},
    }
    (tmp_path / "ballbar.yaml").write_text(yaml.safe_dump(mapping))
    import_tables(tmp_path / "ballbar.yaml", tmp_path / "out")
    imported = load_dataset(tmp_path / "out")
    np.testing.assert_allclose(imported.q, data.q, rtol=1e-15)
    assert list(imported.tables["distances"].ids["pivot"]) == list(table.ids["pivot"])
    np.testing.assert_allclose(imported.tables["distances"].values, table.values, rtol=1e-14)


BAD_MAPPINGS = [
    # (change to the mapping, field or place named, message)
    (("tracker_points", "xyz", ["X [mm]", "Y [mm]", "Zed"]), r"tracker_points\.xyz\[2\]", r"no column 'Zed'.*X \[mm\]"),
    (("configurations", "joints", ["A1", "A2", "A3", "A4", "A5"]), r"configurations\.joints", "has 6 joints"),
    (("tracker_poses", "euler", {"columns": [5, 6, 7], "sequence": "XXY"}), "sequence", "no Euler sequence"),
    (("tracker_poses", "euler", {"columns": [5, 6, 9], "sequence": "ZYX"}), r"columns\[2\]", "column 9 does not exist"),
    (("tracker_poses", "quaternion", [5, 6, 7, 1]), "quaternion", "either quaternion"),
    (("tracker_points", "delimiter", "tab"), r"tracker_points\.config", "no column 'Pose'.*delimiter"),
    (("tracker_points", "colour", "red"), r"tracker_points\.colour", "unknown field"),
    (("tracker_points", "target_name", "t1"), r"tracker_points\.target", "either target"),
    (("tracker_points", "file", "missing.csv"), r"tracker_points\.file", "file not found"),
    (("tracker_points", "file", "points\x00.csv"), r"tracker_points\.file", "a file name with a NUL character"),
    (("tracker_points", "units", {"length": "furlong"}), r"tracker_points\.units\.length", "unknown length unit"),
]


@pytest.mark.parametrize("change, field, message", BAD_MAPPINGS)
def test_bad_mappings_name_the_field(probe_session, tmp_path, change, field, message):
    mapping = _exports(probe_session, tmp_path)
    table, key, value = change
    mapping[table][key] = value
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    with pytest.raises(InputError) as info:
        import_tables(tmp_path / "mapping.yaml", tmp_path / "out")
    text = str(info.value)
    assert str(tmp_path / "mapping.yaml") in text
    assert re.search(field, text) and re.search(message, text), text


def test_a_decimal_comma_with_a_comma_delimiter_is_refused(probe_session, tmp_path):
    mapping = _exports(probe_session, tmp_path)
    mapping["tracker_points"].update(delimiter=",", decimal=",")
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    with pytest.raises(InputError, match=r"tracker_points\.decimal: a decimal comma needs another delimiter"):
        import_tables(tmp_path / "mapping.yaml", tmp_path / "out")


def _break(path: Path, line: int, column: int, new: str) -> None:
    """Replace one cell (0-based column) of a line (1-based, as an editor shows it)."""
    lines = path.read_text().splitlines()
    delimiter = ";" if ";" in lines[line - 1] else ","
    cells = lines[line - 1].split(delimiter)
    cells[column] = new
    lines[line - 1] = delimiter.join(cells)
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(
    "file, line, column, new, message",
    [
        ("controller.csv", 5, 1, "nan", r"controller\.csv: line 5, column A1: must be finite"),
        ("controller.csv", 6, 2, "12x", r"controller\.csv: line 6, column A2: not a number: '12x'"),
        ("controller.csv", 7, 6, "1e40", r"controller\.csv: line 7, column A6: implausible value"),
        ("controller.csv", 8, 1, "1;2", r"controller\.csv: line 8: expected 7 columns, got 8"),
        ("controller.csv", 9, 0, "P100", r"controller\.csv: line 9: configuration 'P100' appears twice"),
        ("controller.csv", 10, 0, "", r"controller\.csv: line 10, column Pose: empty id"),
        ("tracker.csv", 3, 0, "Q1", r"tracker\.csv: line 3, column Pose: unknown configuration 'Q1'"),
        ("tracker.csv", 4, 1, "", r"tracker\.csv: line 4, column Name: empty target name"),
        ("tracker.csv", 5, 1, "t1,", r"tracker\.csv: line 5: expected 5 columns, got 6"),
        ("tracker.csv", 6, 3, "", r"tracker\.csv: line 6, column Y \[mm\]: not a number: ''"),
    ],
)
def test_bad_cells_name_file_line_and_column(probe_session, tmp_path, file, line, column, new, message):
    """A reading whose every value is empty is "not found"; one empty coordinate is damage."""
    _exports(probe_session, tmp_path)
    _break(tmp_path / file, line, column, new)
    with pytest.raises(InputError, match=message):
        import_tables(tmp_path / "mapping.yaml", tmp_path / "out")


def test_rows_joined_by_order_must_match_in_number(probe_session, tmp_path):
    mapping = _exports(probe_session, tmp_path)
    del mapping["tracker_poses"]["config"]
    mapping["tracker_poses"].update(xyz=[2, 3, 4])
    lines = (tmp_path / "probe.txt").read_text().splitlines()[:-1]
    (tmp_path / "probe.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    with pytest.raises(InputError, match=r"probe\.txt: 99 rows, but there are 100 configurations"):
        import_tables(tmp_path / "mapping.yaml", tmp_path / "out")


def test_the_command_reports_bad_input_without_a_traceback(probe_session, tmp_path):
    mapping = _exports(probe_session, tmp_path)
    ok = subprocess.run(
        [sys.executable, "-m", "fgcal", "import-csv", "mapping.yaml", "--out", "dataset"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stderr
    assert "tracker_points_dropped_not_found 1" in ok.stdout
    mapping["format"] = "fgcal-import/9"
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    (tmp_path / "broken.yaml").write_text("format: [unclosed\n")
    for name, expected in (("mapping.yaml", "unsupported format"), ("broken.yaml", "malformed YAML")):
        bad = subprocess.run(
            [sys.executable, "-m", "fgcal", "import-csv", name, "--out", "x"],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert bad.returncode == 2 and expected in bad.stderr and "Traceback" not in bad.stderr


def test_quaternion_columns_and_their_norm(probe_session, tmp_path):
    """Quaternion exports (scalar first) come through as they are; one that is no rotation
    is refused with its line."""
    mapping = _exports(probe_session, tmp_path)
    poses = load_dataset(probe_session).tables["tracker_poses"]
    ids = [f"P{i + 1:03d}" for i in load_dataset(probe_session).config_index(poses.ids["config"])]
    rows = [",".join([c, *(repr(float(v)) for v in value)]) for c, value in zip(ids, poses.values, strict=True)]
    (tmp_path / "probe.csv").write_text("id,x,y,z,q0,q1,q2,q3\n" + "\n".join(rows) + "\n")
    mapping["tracker_poses"] = {
        "file": "probe.csv",
        "units": {"length": "m"},
        "config": "id",
        "xyz": ["x", "y", "z"],
        "quaternion": ["q0", "q1", "q2", "q3"],
    }
    (tmp_path / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    import_tables(tmp_path / "mapping.yaml", tmp_path / "out")
    np.testing.assert_allclose(load_dataset(tmp_path / "out").tables["tracker_poses"].values, poses.values, rtol=1e-15)
    _break(tmp_path / "probe.csv", 3, 4, "0.5")
    with pytest.raises(InputError, match=r"probe\.csv: line 3: quaternion norm .* is not 1"):
        import_tables(tmp_path / "mapping.yaml", tmp_path / "out")


def test_distances_between_configurations(tmp_path):
    """A gauge's log of readings between two configurations names both ends; one end that is
    no configuration, or a missing second column, is refused."""
    np.savetxt(tmp_path / "joints.txt", np.linspace(0.0, 0.5, 24).reshape(4, 6))
    (tmp_path / "gauge.csv").write_text("from,to,mm\nc0000,c0001,150.25\nc0002,c0003,99.5\nc0001,c0003,\n")
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "units": {"length": "mm", "angle": "rad"},
        "configurations": {"file": "joints.txt", "header": False, "joints": [1, 2, 3, 4, 5, 6]},
        "tool_distances": {"file": "gauge.csv", "config_a": "from", "config_b": "to", "distance": "mm"},
    }
    (tmp_path / "gauge.yaml").write_text(yaml.safe_dump(mapping))
    counts = import_tables(tmp_path / "gauge.yaml", tmp_path / "out")
    assert counts["tool_distances"] == 2 and counts["tool_distances_dropped_not_found"] == 1
    table = load_dataset(tmp_path / "out").tables["tool_distances"]
    assert list(table.ids["config_a"]) == ["c0000", "c0002"] and list(table.ids["config_b"]) == ["c0001", "c0003"]
    np.testing.assert_allclose(table.values[:, 0], [0.15025, 0.0995], rtol=1e-15)
    (tmp_path / "gauge.csv").write_text("from,to,mm\nc0000,c0009,150.25\n")
    with pytest.raises(InputError, match=r"gauge\.csv: line 2, column to: unknown configuration 'c0009'"):
        import_tables(tmp_path / "gauge.yaml", tmp_path / "out")
    del mapping["tool_distances"]["config_b"]
    (tmp_path / "gauge.yaml").write_text(yaml.safe_dump(mapping))
    with pytest.raises(InputError, match=r"tool_distances\.config_a: .* config_a and config_b"):
        import_tables(tmp_path / "gauge.yaml", tmp_path / "out")


def test_the_joint_log_carries_the_motion_history(probe_session, tmp_path):
    """Issue 25: the log's rows are the measurement order; an approach column set and a speed
    column come through as before_q1..n and speed (empty approach cells: the row before)."""
    _exports(probe_session, tmp_path / "exports")
    log = tmp_path / "exports" / "controller.csv"
    lines = log.read_text().splitlines()
    lines[2] += ";B1;B2;B3;B4;B5;B6;Speed"
    for k in range(3, len(lines)):
        lines[k] += ";;;;;;;" if k != 5 else ";1,5;2;3;4;5;6;0,5"
    log.write_text("\n".join(lines) + "\n")
    mapping = yaml.safe_load((tmp_path / "exports" / "mapping.yaml").read_text())
    mapping["configurations"]["approach"] = ["B1", "B2", "B3", "B4", "B5", "B6"]
    mapping["configurations"]["speed"] = "Speed"
    (tmp_path / "exports" / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    import_tables(tmp_path / "exports" / "mapping.yaml", tmp_path / "dataset")
    imported = load_dataset(tmp_path / "dataset")
    history = imported.motion_history
    assert imported.header["order"] == "measured"
    np.testing.assert_allclose(history.before[2], np.radians([1.5, 2, 3, 4, 5, 6]))
    np.testing.assert_allclose(history.before[3], imported.q[2])  # the row before, in the log's order
    assert history.speed[2] == 0.5 and history.speed[3] == 1.0
