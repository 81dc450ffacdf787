"""The bad-input corpus of the surfaces added after issue 13 (issue 23): URDF files, the
importer, compensate, plan, export, simulate's options, every numeric option, degenerate and
duplicated data, and files a dataset names outside its folder. One row per damaged input; each
runs an ``fgcal`` command in-process and expects exit status 2 with one line naming the file
(or option) and the field, no traceback, within a bounded time. The first corpus
(tests/test_bad_input_corpus.py) covers the files of issue 13; the online inbox has its own
tests (tests/test_online_inbox.py)."""

from __future__ import annotations

import csv
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, SEED_CELL
from test_bad_input import alarm  # noqa: F401 (a fixture)

from fgcal.commands.cli import main

CELLS = REPO / "datasets" / "cells"
IRB120 = REPO / "datasets" / "robots" / "abb_irb120.yaml"

# A small valid URDF: every URDF case changes one thing of it.
URDF = (
    "<robot name='r'><link name='base'/>"
    "<link name='l1'><inertial><mass value='2'/><origin xyz='0 0 0.1'/></inertial></link><link name='tool0'/>"
    "<joint name='j1' type='revolute'><parent link='base'/><child link='l1'/><origin xyz='0 0 0.3' rpy='0 0 0'/>"
    "<axis xyz='0 0 1'/><limit lower='-3' upper='3' effort='1' velocity='1'/></joint>"
    "<joint name='t' type='fixed'><parent link='l1'/><child link='tool0'/><origin xyz='0.1 0 0'/></joint></robot>"
)


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """What the cases damage: the seed cell simulated (camera points, pixels, tracker), a
    robot file, the small URDF, compensation targets and an importer's exports with their
    mapping."""
    from fgcal.model.robot_io import load_robot
    from fgcal.simulation.simulate import simulate

    root = tmp_path_factory.mktemp("surfaces")
    simulate(SEED_CELL, root / "data", seed=5)
    shutil.copy(IRB120, root / "robot.yaml")
    (root / "good.urdf").write_text(URDF)
    robot = load_robot("abb_irb120")
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.limits[:, 0] / 2, robot.limits[:, 1] / 2, (6, 6))
    positions = robot.fk_tool(q)[:, :3, 3]
    _write(root / "targets.csv", ["target", "x", "y", "z"], [[f"T{i}", *p] for i, p in enumerate(positions)])
    _write(root / "controller.csv", ["pose", *[f"A{i}" for i in range(1, 7)]],
           [[f"P{i}", *np.rad2deg(qi)] for i, qi in enumerate(q)])  # fmt: skip
    _write(root / "tracker.csv", ["pose", "name", "x", "y", "z"],
           [[f"P{i}", "t1", *(p * 1e3)] for i, p in enumerate(positions)])  # fmt: skip
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "units": {"length": "mm", "angle": "deg"},
        "configurations": {"file": "controller.csv", "config": "pose", "joints": [f"A{i}" for i in range(1, 7)]},
        "tracker_points": {"file": "tracker.csv", "config": "pose", "target": "name", "xyz": ["x", "y", "z"]},
    }
    (root / "mapping.yaml").write_text(yaml.safe_dump(mapping, sort_keys=False))
    (root / "calibration.yaml").write_text("dataset: data\n")
    return root


def _write(path: Path, header: list[str], rows: list[list]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)


# --- damages: each takes the case's folder and returns the command line -----------------------


def _urdf(old: str, new: str, *, tip: str | None = None):
    def apply(root: Path) -> list[str]:
        assert old in URDF
        (root / "bad.urdf").write_text(URDF.replace(old, new, 1))
        return ["fk", "bad.urdf", *(["--tip", tip] if tip else []), "0"]

    return apply


def _urdf_text(text: str | bytes):
    def apply(root: Path) -> list[str]:
        path = root / "bad.urdf"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        return ["fk", "bad.urdf", "0"]

    return apply


def _loop(root: Path) -> list[str]:
    (root / "bad.urdf").write_text(
        "<robot name='r'><link name='a'/><link name='b'/><link name='c'/>"
        "<joint name='ab' type='continuous'><parent link='a'/><child link='b'/></joint>"
        "<joint name='bc' type='continuous'><parent link='b'/><child link='c'/></joint>"
        "<joint name='ca' type='continuous'><parent link='c'/><child link='a'/></joint></robot>"
    )
    return ["fk", "bad.urdf", "0"]


def _deep_loop(root: Path) -> list[str]:
    """Five thousand links deep, its last joint back to the first link (the recursion limit)."""
    n = 5000
    links = "".join(f"<link name='l{i}'/>" for i in range(n))
    joints = "".join(
        f"<joint name='j{i}' type='fixed'><parent link='l{i}'/><child link='l{(i + 1) % n}'/></joint>" for i in range(n)
    )
    (root / "bad.urdf").write_text(f"<robot name='deep'>{links}{joints}</robot>")
    return ["fk", "bad.urdf", "0"]


def _fifo(name: str, command: Callable[[str], list[str]]):
    def apply(root: Path) -> list[str]:
        os.mkfifo(root / name)
        return command(name)

    return apply


def _mapping(change: Callable[[dict], None]):
    def apply(root: Path) -> list[str]:
        path = root / "mapping.yaml"
        doc = yaml.safe_load(path.read_text())
        change(doc)
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return ["import-csv", "mapping.yaml", "--out", "imported"]

    return apply


def _set(path: str, value):
    def change(doc: dict) -> None:
        *parents, last = path.split(".")
        node = doc
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = value

    return change


def _export_line(name: str, line: int, column: int, text: str):
    """Replace one cell of an export (line 1 is the header)."""

    def apply(root: Path) -> list[str]:
        path = root / name
        rows = list(csv.reader(path.read_text().splitlines()))
        rows[line - 1][column] = text
        _write(path, rows[0], rows[1:])
        return ["import-csv", "mapping.yaml", "--out", "imported"]

    return apply


def _import_then(prepare: Callable[[Path], None]):
    def apply(root: Path) -> list[str]:
        prepare(root)
        return ["import-csv", "mapping.yaml", "--out", "imported"]

    return apply


def _targets(lines: list[str] | None = None, *more: str, out: str = "commands.csv", robot: str = "abb_irb120"):
    def apply(root: Path) -> list[str]:
        if lines is not None:
            (root / "targets.csv").write_text("\n".join(lines) + "\n")
        return ["compensate", robot, "targets.csv", "--out", out, *more]

    return apply


def _prepare_then(prepare: Callable[[Path], None], argv: list[str]):
    def apply(root: Path) -> list[str]:
        prepare(root)
        return argv

    return apply


def _link_in(folder: str, name: str):
    """A link where an output goes, inside the output folder, to a file outside it."""

    def apply(root: Path) -> None:
        (root / folder).mkdir()
        os.symlink(root / "robot.yaml", root / folder / name)

    return apply


def _argv(*argv: str):
    return lambda root: list(argv)


RAPID_TARGET = "MODULE M\nCONST robtarget p1:=[[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
RAPID_TOOL = RAPID_TARGET + "PERS tooldata gun:=[TRUE,[[0,0,100],[1,0,0,0]],[0.5,[0,0,30],[1,0,0,0],0,0,0]];\n"
RAPID_WOBJ = RAPID_TARGET + 'PERS wobjdata table:=[FALSE,TRUE,"",[[0,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];\n'


def _program(name: str, text: str, out: str = "o.mod", extra: list[str] | None = None):
    """A robot program, corrected by fgcal compensate for the IRB 120."""

    def apply(root: Path) -> list[str]:
        (root / name).write_text(text if "ENDMODULE" in text or name.endswith(".dat") else text + "ENDMODULE\n")
        return ["compensate", "abb_irb120", name, "--out", out, *(extra or [])]

    return apply


def _robot_edit(line: str):
    """robot.yaml with one more top-level entry, read by fgcal fk."""

    def apply(root: Path) -> list[str]:
        with open(root / "robot.yaml", "a") as fh:
            fh.write("\n" + line + "\n")
        return ["fk", "robot.yaml", "0", "0", "0", "0", "0", "0"]

    return apply


def _cell(name: str, edit: Callable[[str], str]):
    """A bundled cell's text, edited, as cell.yaml."""

    def apply(root: Path) -> list[str]:
        text = (CELLS / f"{name}.yaml").read_text()
        edited = edit(text)
        assert edited != text
        (root / "cell.yaml").write_text(edited)
        return ["simulate", "cell.yaml", "--out", "sim"]

    return apply


def _table(name: str, change: Callable[[list[str]], list[str]], config: str = "dataset: data\n"):
    def apply(root: Path) -> list[str]:
        path = root / "data" / name
        path.write_text("\n".join(change(path.read_text().splitlines())) + "\n")
        (root / "calibration.yaml").write_text(config)
        return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]

    return apply


def _header(change: Callable[[dict], None], config: str = "dataset: data\n"):
    def apply(root: Path) -> list[str]:
        path = root / "data" / "dataset.yaml"
        doc = yaml.safe_load(path.read_text())
        change(doc)
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        (root / "calibration.yaml").write_text(config)
        return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]

    return apply


def _formulation(name: str):
    def apply(root: Path) -> list[str]:
        (root / "calibration.yaml").write_text(f"dataset: data\nformulation: {name}\n")
        return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]

    return apply


def _joint_turned(row: int, config: str):
    """One configuration's first joint turned half a turn: its images cannot be where they are."""

    def apply(root: Path) -> list[str]:
        path = root / "data" / "configurations.csv"
        rows = list(csv.reader(path.read_text().splitlines()))
        rows[row][1] = repr(float(rows[row][1]) + 3.0)
        _write(path, rows[0], rows[1:])
        (root / "calibration.yaml").write_text(config)
        return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]

    return apply


def _online(*more: str, inbox: str = "inbox", state: str = "state"):
    def apply(root: Path) -> list[str]:
        (root / "setup.yaml").write_text("dataset: data\n")
        (root / "inbox").mkdir(exist_ok=True)
        return ["online", "--state", state, "--inbox", inbox, "--setup", "setup.yaml", "--once", *more]

    return apply


def _state_is_a_file(root: Path) -> list[str]:
    (root / "state").write_text("not a folder\n")
    return _online()(root)


def _config_text(more: str):
    """The calibration config with more lines."""

    def apply(root: Path) -> list[str]:
        (root / "calibration.yaml").write_text("dataset: data\n" + more)
        return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]

    return apply


def _on_a_line(lines: list[str]) -> list[str]:
    """Every drawing point moved onto the fixture's x axis."""
    rows = list(csv.reader(lines))
    y, z = rows[0].index("y"), rows[0].index("z")
    for row in rows[1:]:
        row[y] = row[z] = "0"
    return [",".join(row) for row in rows]


def _renamed_target(root: Path) -> list[str]:
    """A tracker row's target renamed, the header's list of targets gone: the fit takes it as a
    fourth reflector, and the score against the simulation's truth cannot."""
    path = root / "data" / "dataset.yaml"
    doc = yaml.safe_load(path.read_text())
    del doc["tracker"]
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    table = root / "data" / "tracker_points.csv"
    lines = table.read_text().splitlines()
    cells = lines[1].split(",")
    cells[1] = "T9"
    lines[1] = ",".join(cells)
    table.write_text("\n".join(lines) + "\n")
    (root / "calibration.yaml").write_text("dataset: data\nformulation: tracker\n")
    return ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]


def _fixed_camera_online(root: Path) -> list[str]:
    """A dataset whose camera has no mounting (fixed in the cell), given to fgcal online."""
    path = root / "data" / "dataset.yaml"
    doc = yaml.safe_load(path.read_text())
    del doc["camera"]["mounting"]
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return _online()(root)


def _online_setup(text: str):
    def apply(root: Path) -> list[str]:
        (root / "setup.yaml").write_text(text)
        (root / "inbox").mkdir(exist_ok=True)
        return ["online", "--state", "state", "--inbox", "inbox", "--setup", "setup.yaml", "--once"]

    return apply


def _faro_dev_zero(root: Path) -> None:
    (root / "faro").mkdir()
    os.symlink("/dev/zero", root / "faro" / "measured_joints.txt")
    (root / "faro" / "measured_SMR_1.txt").write_text("1 2 3\n")


def _seven_joint_file(root: Path) -> None:
    _write(root / "seven.csv", ["config", *[f"q{i}" for i in range(1, 8)]], [["c0", 0, 0, 0, 0, 0, 0, 0]])


PLAN = ["plan", "kr125_seed", "--out", "plan", "--no-plots"]
LOST_MOTION_CELL = (REPO / "datasets" / "cells" / "irb120_tracker_lost_motion.yaml").read_text()


def _text(name: str, text: str) -> Callable[[Path], None]:
    def write(root: Path) -> None:
        (root / name).write_text(text)

    return write


DUPLICATE_ROW = 3  # a measurement row given again at the end of its table

# (case id, damage, file or option named, field named)
CASES = [
    # URDF (fgcal fk): a well-formed <robot> of unique names, vectors of the right length,
    # finite bounded numbers, a tree, a tip that exists.
    ("urdf_two_links_one_name", _urdf("<link name='tool0'/>", "<link name='tool0'/><link name='l1'/>"),
     "bad.urdf", "link l1"),
    ("urdf_two_joints_one_name", _urdf("<joint name='t'", "<joint name='j1'"), "bad.urdf", "joint j1"),
    ("urdf_origin_four_values", _urdf("xyz='0 0 0.3'", "xyz='0 0 1 5'"), "bad.urdf", "j1.origin.xyz"),
    ("urdf_origin_two_values", _urdf("xyz='0.1 0 0'", "xyz='0.1 0'"), "bad.urdf", "t.origin.xyz"),
    ("urdf_origin_text", _urdf("xyz='0 0 0.3'", "xyz='0 zero 0.3'"), "bad.urdf", "j1.origin.xyz"),
    ("urdf_origin_huge", _urdf("xyz='0 0 0.3'", "xyz='0 0 1e300'"), "bad.urdf", "j1.origin.xyz"),
    ("urdf_rpy_huge", _urdf("rpy='0 0 0'", "rpy='0 0 1e300'"), "bad.urdf", "j1.origin.rpy"),
    ("urdf_rpy_nan", _urdf("rpy='0 0 0'", "rpy='0 nan 0'"), "bad.urdf", "j1.origin.rpy"),
    ("urdf_axis_two_values", _urdf("<axis xyz='0 0 1'/>", "<axis xyz='0 1'/>"), "bad.urdf", "j1.axis"),
    ("urdf_limits_huge", _urdf("lower='-3' upper='3'", "lower='-1e300' upper='1e300'"), "bad.urdf", "limit.lower"),
    ("urdf_limit_inf", _urdf("upper='3'", "upper='inf'"), "bad.urdf", "j1.limit.upper"),
    ("urdf_limit_text", _urdf("upper='3'", "upper='three'"), "bad.urdf", "j1.limit.upper"),
    ("urdf_sdf_root", _urdf_text("<sdf version='1.6'><model name='m'/></sdf>"), "bad.urdf", "not a URDF"),
    ("urdf_html_root", _urdf_text("<html><body>404</body></html>"), "bad.urdf", "<html>"),
    ("urdf_unnamed_link", _urdf("<link name='tool0'/>", "<link name='tool0'/><link/>"), "bad.urdf", "link"),
    ("urdf_joint_to_missing_link", _urdf("<child link='tool0'/>", "<child link='tool9'/>"), "bad.urdf",
     "t.child"),
    ("urdf_child_of_two_joints", _urdf("</robot>", "<joint name='k' type='fixed'><parent link='base'/>"
     "<child link='tool0'/></joint></robot>"), "bad.urdf", "child of two joints"),
    ("urdf_loop", _loop, "bad.urdf", "loop"),
    ("urdf_deep_loop", _deep_loop, "bad.urdf", "loop"),
    ("urdf_ghost_tip", _urdf("</robot>", "</robot>", tip="ghost"), "bad.urdf", "no link 'ghost'"),
    ("urdf_mass_negative", _urdf("<mass value='2'/>", "<mass value='-2'/>"), "bad.urdf", "l1.inertial.mass"),
    ("urdf_mass_huge", _urdf("<mass value='2'/>", "<mass value='1e300'/>"), "bad.urdf", "l1.inertial.mass"),
    ("urdf_malformed", _urdf_text(URDF[:-9]), "bad.urdf", "malformed XML"),
    ("urdf_empty", _urdf_text(""), "bad.urdf", "malformed XML"),
    ("urdf_binary", _urdf_text(b"\x89PNG\r\n\x1a\n\x00\x00"), "bad.urdf", "not utf-8"),
    ("urdf_entity", _urdf_text("<!DOCTYPE r [<!ENTITY x SYSTEM 'file:///etc/passwd'>]><robot name='&x;'/>"),
     "bad.urdf", ""),
    ("urdf_fifo", _fifo("pipe.urdf", lambda name: ["fk", name, "0"]), "pipe.urdf", "not a regular file"),
    ("urdf_folder", _prepare_then(lambda root: (root / "dir.urdf").mkdir(), ["fk", "dir.urdf", "0"]),
     "dir.urdf", "not a regular file"),
    ("urdf_dev_zero", _argv("export", "/dev/zero", "--urdf", "x.urdf"), "/dev/zero", "no such robot"),
    # The importer (fgcal import-csv)
    ("import_nul_in_target", _export_line("tracker.csv", 3, 1, "t\x001"), "tracker.csv", "control character"),
    ("import_control_in_config", _export_line("controller.csv", 2, 0, "P\x070"), "controller.csv",
     "control character"),
    ("import_field_200kB", _export_line("tracker.csv", 2, 1, '"' + "t" * 200_000), "tracker.csv", "not CSV"),
    ("import_out_is_a_file", _prepare_then(lambda root: (root / "imported").write_text("x"),
     ["import-csv", "mapping.yaml", "--out", "imported"]), "imported", "is a file"),
    ("import_link_in_out", _prepare_then(_link_in("imported", "configurations.csv"),
     ["import-csv", "mapping.yaml", "--out", "imported"]), "configurations.csv", "symbolic link"),
    ("import_source_dev_zero", _mapping(_set("tracker_points.file", "/dev/zero")), "mapping.yaml",
     "not a regular file"),
    ("import_source_fifo", _fifo("pipe.csv", lambda name: _mapping(_set("tracker_points.file", name))(
     Path.cwd())), "mapping.yaml", "not a regular file"),
    ("import_source_missing", _mapping(_set("tracker_points.file", "nowhere.csv")), "mapping.yaml",
     "tracker_points.file"),
    ("import_unknown_encoding", _mapping(_set("tracker_points.encoding", "klingon")), "mapping.yaml",
     "tracker_points.encoding"),
    ("import_unknown_column", _mapping(_set("tracker_points.target", "reflector")), "mapping.yaml",
     "tracker_points.target"),
    ("import_joint_count", _mapping(_set("configurations.joints", ["A1", "A2"])), "mapping.yaml",
     "configurations.joints"),
    ("import_unknown_robot", _mapping(_set("robot", "robot9000")), "mapping.yaml", "robot"),
    ("import_duplicate_pose", _export_line("controller.csv", 3, 0, "P0"), "controller.csv", "P0"),
    ("import_nan_joint", _export_line("controller.csv", 2, 3, "nan"), "controller.csv", "line 2"),
    ("import_duplicate_reading", _import_then(lambda root: (root / "tracker.csv").write_text(
     (root / "tracker.csv").read_text() + (root / "tracker.csv").read_text().splitlines()[2] + "\n")),
     "tracker.csv", "lines 3 and 8"),
    ("import_joint_column_twice", _mapping(_set("configurations.joints", ["A1", "A1", "A3", "A4", "A5", "A6"])),
     "mapping.yaml", "configurations.joints[1]"),
    ("import_header_column_twice", _import_then(lambda root: (root / "tracker.csv").write_text(
     (root / "tracker.csv").read_text().replace("pose,name,x,y,z", "pose,name,x,x,z", 1))), "tracker.csv",
     "'x' twice"),
    ("import_mapping_fifo", _fifo("pipe.yaml", lambda name: ["import-csv", name, "--out", "imported"]),
     "pipe.yaml", "not a regular file"),
    # fgcal compensate
    ("compensate_out_is_a_folder", _targets(None, out="data"), "data", "folder"),
    ("compensate_out_in_missing_folder", _targets(None, out="nowhere/commands.csv"), "commands.csv",
     "no such folder"),
    ("compensate_out_is_a_link", _prepare_then(lambda root: os.symlink(root / "robot.yaml", root / "c.csv"),
     ["compensate", "abb_irb120", "targets.csv", "--out", "c.csv"]), "c.csv", "symbolic link"),
    ("compensate_target_nan", _targets(["target,x,y,z", "T0,0.4,nan,0.5"]), "targets.csv", "column y"),
    ("compensate_target_huge", _targets(["target,x,y,z", "T0,0.4,1e300,0.5"]), "targets.csv", "column y"),
    ("compensate_no_targets", _targets(["target,x,y,z"]), "targets.csv", "no targets"),
    ("compensate_missing_column", _targets(["target,x,y", "T0,0.4,0.1"]), "targets.csv", "z"),
    ("compensate_duplicate_target", _targets(["target,x,y,z", "T0,0.4,0,0.5", "T0,0.4,0.1,0.5"]),
     "targets.csv", "lines 2 and 3"),
    ("compensate_control_in_name", _targets(["target,x,y,z", "T\x1b0,0.4,0,0.5"]), "targets.csv",
     "control character"),
    ("compensate_half_rotation", _targets(["target,x,y,z,rx", "T0,0.4,0,0.5,0"]), "targets.csv", "rx, ry"),
    ("compensate_tcp_nan", _targets(None, "--tcp", "0", "0", "nan"), "fgcal compensate", "--tcp"),
    ("compensate_tolerance_zero", _targets(None, "--tolerance-um", "0"), "fgcal compensate", "--tolerance-um"),
    ("compensate_payload_negative", _targets(None, "--payload-mass", "-1"), "fgcal compensate", "--payload-mass"),
    ("compensate_payload_com_huge", _targets(None, "--payload-com", "0", "0", "1e9"), "fgcal compensate",
     "--payload-com"),
    ("compensate_nominal_other_arm", _targets(None, "--nominal", "seven_axis"), "--nominal", "joints"),
    ("compensate_nominal_of_another_robot", _targets(None, "--nominal", "kuka_kr125_2"), "--nominal",
     "is not a nominal model"),
    ("compensate_unknown_robot", _targets(None, robot="robot9000"), "robot9000", "no such robot"),
    ("compensate_targets_fifo", _fifo("t.csv", lambda name: ["compensate", "abb_irb120", name, "--out", "c.csv"]),
     "t.csv", "not a regular file"),
    # fgcal plan
    ("plan_n_zero", _argv(*PLAN, "--n", "0"), "fgcal plan", "--n"),
    ("plan_n_negative", _argv(*PLAN, "--n", "-5"), "fgcal plan", "--n"),
    ("plan_n_text", _argv(*PLAN, "--n", "ten"), "fgcal plan", "--n"),
    ("plan_n_above_candidates", _argv(*PLAN, "--n", "600", "--candidates", "500"), "--n", "candidates"),
    ("plan_n_huge", _argv(*PLAN, "--n", "100000000"), "fgcal plan", "--n"),
    ("plan_candidates_zero", _argv(*PLAN, "--n", "10", "--candidates", "0"), "fgcal plan", "--candidates"),
    ("plan_candidates_huge", _argv(*PLAN, "--n", "10", "--candidates", "10000000"), "fgcal plan", "--candidates"),
    ("plan_unknown_formulation", _argv(*PLAN, "--n", "10", "--formulation", "sonar"), "--formulation", "sonar"),
    ("plan_formulation_not_planned", _argv(*PLAN, "--n", "10", "--formulation", "poses"), "--formulation",
     "not planned"),
    # Issue 42: touch is planned; a cell without a probe is told so
    ("plan_touch_on_camera_cell", _argv(*PLAN, "--n", "10", "--formulation", "touch"), "kr125_seed", "touch"),
    ("plan_seed_negative", _argv(*PLAN, "--n", "10", "--seed", "-1"), "fgcal plan", "--seed"),
    # Issue 42: a ballbar's readings to pivots are planned, those between configurations not yet
    ("plan_ball_pairs_cell", _argv("plan", "irb120_ball_pairs", "--n", "10", "--out", "plan"), "irb120_ball_pairs",
     "not planned yet"),
    ("plan_tracker_on_ballbar_cell", _argv("plan", "irb120_ballbar", "--n", "10", "--out", "plan",
     "--formulation", "tracker"), "irb120_ballbar", "tracker"),
    # fgcal simulate
    ("simulate_pivot_out_of_reach", _cell("irb120_ballbar", lambda t: t.replace("[420, 0, 150]", "[5000, 0, 150]")),
     "cell.yaml", "ballbar.pivots"),
    ("simulate_pairs_sphere_out_of_reach", _cell("irb120_ball_pairs", lambda t: t.replace("[350, 0, 250]",
     "[350, 0, 2500]")), "cell.yaml", "ballbar.between_configurations"),
    ("simulate_touch_point_out_of_reach", _cell("seven_axis_touch", lambda t: t.replace("[550, -250", "[9000, -250")),
     "cell.yaml", "touch"),
    ("simulate_tracker_without_reflectors", _cell("irb120_tracker", lambda t: t.replace(
     "targets: [[40, 0, 30], [-20, 35, 30], [-20, -35, 30]]", "targets: []")), "cell.yaml", "tracker.targets"),
    ("simulate_n_million", _argv("simulate", "irb120_tracker", "--out", "sim", "--n", "1000000"), "fgcal simulate",
     "--n"),
    ("simulate_n_zero", _argv("simulate", "irb120_tracker", "--out", "sim", "--n", "0"), "fgcal simulate", "--n"),
    ("simulate_seed_negative", _argv("simulate", "irb120_tracker", "--out", "sim", "--seed", "-3"),
     "fgcal simulate", "--seed"),
    ("simulate_drift_static_camera", _argv("simulate", "irb120_static_camera", "--out", "sim", "--drift",
     "theta2=0.001@10"), "static_camera", "a static-camera cell: no drift"),
    ("simulate_drift_malformed", _argv("simulate", "kr125_seed", "--out", "sim", "--drift", "theta2"), "--drift",
     "NAME=CHANGE@CONFIGURATION"),
    ("simulate_drift_huge", _argv("simulate", "kr125_seed", "--out", "sim", "--drift", "theta2=1e300@3"), "--drift",
     "at most"),
    ("simulate_drift_unknown_parameter", _argv("simulate", "kr125_seed", "--out", "sim", "--drift", "zeta9=0.001@3"),
     "drift", "zeta9"),
    ("simulate_drift_after_the_design", _argv("simulate", "kr125_seed", "--out", "sim", "--drift",
     "theta2=0.001@5000"), "--drift", "starts at configuration 5000"),
    ("simulate_render_tracker_cell", _argv("simulate", "irb120_tracker", "--out", "sim", "--render"), "irb120_tracker",
     "camera"),
    ("simulate_configurations_of_seven_joints", _prepare_then(_seven_joint_file, ["simulate", "irb120_tracker",
     "--out", "sim", "--configurations", "seven.csv"]), "seven.csv", "column q7"),
    ("simulate_unknown_cell", _argv("simulate", "no_such_cell", "--out", "sim"), "no_such_cell", "bundled"),
    ("simulate_out_is_a_file", _argv("simulate", "irb120_tracker", "--out", "robot.yaml"), "robot.yaml", "is a file"),
    # fgcal calibrate: degenerate and duplicated data, formulations the data cannot serve,
    # files outside the dataset's folder
    ("calibrate_point_behind_camera_fit", _joint_turned(9, "dataset: data\nformulation: projection\n"),
     "configurations.csv", "configuration c0008"),
    ("calibrate_point_behind_camera_held_out", _joint_turned(12, "dataset: data\nformulation: projection\n"),
     "configurations.csv", "configuration c0011"),
    ("calibrate_poses_without_poses", _formulation("poses"), "dataset.yaml", "tracker_poses"),
    ("calibrate_touch_without_touches", _formulation("touch"), "dataset.yaml", "touch_points"),
    ("calibrate_distances_without_distances", _formulation("distances"), "dataset.yaml", "distances"),
    ("calibrate_static_camera_on_the_flange", _formulation("static_camera"), "dataset.yaml", "camera.mounting"),
    ("calibrate_duplicate_tracker_row", _table("tracker_points.csv", lambda ls: [*ls, ls[DUPLICATE_ROW]]),
     "tracker_points.csv", "given twice"),
    ("calibrate_duplicate_camera_point", _table("camera_points.csv", lambda ls: [*ls, ls[DUPLICATE_ROW]]),
     "camera_points.csv", "given twice"),
    ("calibrate_duplicate_pixel", _table("pixels.csv", lambda ls: [*ls, ls[DUPLICATE_ROW]]), "pixels.csv",
     "given twice"),
    ("calibrate_duplicate_drawing_point", _table("points.csv", lambda ls: [*ls, ls[DUPLICATE_ROW]]), "points.csv",
     "given twice"),
    ("calibrate_robot_outside_dataset", _header(_set("robot", "../robot.yaml")), "dataset.yaml",
     "outside the dataset folder"),
    ("calibrate_robot_absolute_outside", lambda root: _header(_set("robot", str(root / "robot.yaml")))(root),
     "dataset.yaml", "outside the dataset folder"),
    ("calibrate_robot_urdf_outside", _header(_set("robot", {"file": "../good.urdf", "tip": "tool0"})),
     "dataset.yaml", "outside the dataset folder"),
    ("calibrate_images_outside", _header(_set("images", "..")), "dataset.yaml", "outside the dataset directory"),
    ("calibrate_images_absolute", _header(_set("images", "/tmp")), "dataset.yaml", "outside the dataset directory"),
    ("calibrate_table_is_a_fifo", _prepare_then(lambda root: (os.remove(root / "data" / "pixels.csv"),
     os.mkfifo(root / "data" / "pixels.csv")), ["calibrate", "calibration.yaml", "--out", "out"]), "pixels.csv",
     "not a regular file"),
    ("calibrate_out_is_a_file", _argv("calibrate", "calibration.yaml", "--out", "robot.yaml", "--no-plots"),
     "robot.yaml", "is a file"),
    ("calibrate_validation_seed_negative", _config_text("validation: {holdout: 0.25, seed: -1}\n"),
     "calibration.yaml", "validation.seed"),
    ("calibrate_pairs_seed_negative", _config_text("pairs: {seed: -5}\n"), "calibration.yaml", "pairs.seed"),
    ("calibrate_images_for_a_tracker", _config_text("formulation: tracker\npixels_from: images\n"), "calibration.yaml",
     "pixels_from: images: the tracker formulation reads no pixels"),
    ("calibrate_schedule_overruled_by_stages", _config_text("schedule: one_shot\nstages: [[theta], [a]]\n"),
     "calibration.yaml", "write schedule: custom"),
    ("calibrate_key_given_twice", _config_text("validation: {holdout: 0.5}\nvalidation: {holdout: 0.25}\n"),
     "calibration.yaml", "'validation' given twice (first on line 2)"),
    ("calibrate_nested_key_given_twice", _config_text("noise: {tracker_sigma: 1.0e-5, tracker_sigma: 2.0e-5}\n"),
     "calibration.yaml", "'tracker_sigma' given twice"),
    ("calibrate_pairs_seed_huge", _config_text("pairs: {seed: 99999999999999999999}\n"), "calibration.yaml",
     "pairs.seed"),
    ("calibrate_no_stages", _config_text("schedule: custom\nstages: []\n"), "calibration.yaml", "stages"),
    ("calibrate_noise_tiny", _config_text("noise: {tracker_sigma: 1.0e-300}\n"), "calibration.yaml",
     "noise.tracker_sigma"),
    ("calibrate_validation_is_the_fitting_set", _config_text("validation: {dataset: data}\n"), "calibration.yaml",
     "is the fitting set"),
    ("calibrate_unknown_test_point", _config_text("formulation: tracker\nvalidation: {tool_points: {zz: [0, 0, 1]}}\n"),
     "calibration.yaml", "validation.tool_points.zz"),
    ("calibrate_collinear_points", _table("points.csv", _on_a_line, "dataset: data\nformulation: projection\n"),
     "points.csv", "one line"),
    ("calibrate_renamed_target_scored", _renamed_target, "ground_truth.yaml", "'T9'"),
    # fgcal export
    ("export_to_a_folder", _prepare_then(lambda root: (root / "x.urdf").mkdir(),
     ["export", "abb_irb120", "--urdf", "x.urdf"]), "x.urdf", "folder"),
    ("export_not_urdf", _argv("export", "abb_irb120", "--urdf", "x.txt"), "x.txt", "must end in .urdf"),
    ("export_through_a_link", _prepare_then(lambda root: os.symlink(root / "robot.yaml", root / "x.urdf"),
     ["export", "abb_irb120", "--urdf", "x.urdf"]), "x.urdf", "symbolic link"),
    ("export_sidecar_is_a_link", _prepare_then(lambda root: os.symlink(root / "robot.yaml",
     root / "x.compliance.yaml"), ["export", "abb_irb120", "--urdf", "x.urdf"]), "x.compliance.yaml",
     "symbolic link"),
    ("convert_faro_joints_are_dev_zero", _prepare_then(_faro_dev_zero, ["convert-faro", "faro", "--out", "f"]),
     "/dev/zero", "not a regular file"),
    ("export_unknown_robot", _argv("export", "robot9000", "--urdf", "x.urdf"), "robot9000", "no such robot"),
    ("export_ghost_tip", _argv("export", "good.urdf", "--tip", "ghost", "--urdf", "x.urdf"), "good.urdf",
     "no link 'ghost'"),
    # fgcal online and online-feed
    ("online_poll_negative", _online("--poll", "-1"), "fgcal online", "--poll"),
    ("online_poll_nan", _online("--poll", "nan"), "fgcal online", "--poll"),
    ("online_inbox_is_the_state", _online(inbox="state", state="state"), "inbox", "state"),
    ("online_inbox_inside_the_state", _online(inbox="state/inbox"), "inbox", "state"),
    ("online_state_is_a_file", _state_is_a_file, "state", ""),
    ("online_starting_model_of_another_robot", _online_setup("dataset: data\nrobot: abb_irb120\n"), "setup.yaml",
     "is not the dataset's"),
    ("online_camera_fixed_in_the_cell", _fixed_camera_online, "dataset.yaml", "camera.mounting"),
    ("online_compliant_joint_beyond_the_robot", _online_setup("dataset: data\nsettings: {compliant_joints: [9]}\n"),
     "setup.yaml", "settings.compliant_joints"),
    ("online_unknown_formulation", _online_setup("dataset: data\nformulation: laser\n"), "setup.yaml",
     "formulation"),
    ("online_formulation_not_incremental", _online_setup("dataset: data\nformulation: pairs\n"), "setup.yaml",
     "cannot be refined online"),
    ("online_model_without_formulation", _online_setup("dataset: data\nmodel: DH,s,e,h\n"), "setup.yaml",
     "with a formulation"),
    ("online_setup_missing", _argv("online", "--state", "s", "--inbox", "data", "--setup", "nowhere.yaml", "--once"),
     "nowhere.yaml", "file not found"),
    ("feed_first_negative", _argv("online-feed", "data", "--inbox", "in", "--first", "-1"), "fgcal online-feed",
     "--first"),
    ("feed_into_a_file", _argv("online-feed", "data", "--inbox", "robot.yaml"), "robot.yaml", "is a file"),
    ("feed_first_beyond_the_images", _argv("online-feed", "data", "--inbox", "in", "--first", "1000"), "--first",
     "images"),
    ("feed_n_zero", _argv("online-feed", "data", "--inbox", "in", "--n", "0"), "fgcal online-feed", "--n"),
    ("feed_cycle_zero", _argv("online-feed", "data", "--inbox", "in", "--cycle-size", "0"), "fgcal online-feed",
     "--cycle-size"),
    ("feed_table_not_in_the_dataset", _argv("online-feed", "data", "--inbox", "in", "--table", "contacts"), "data",
     "no table 'contacts'"),
    # fgcal fk, bench, demo: their numbers
    ("fk_q_nan", _argv("fk", "abb_irb120", "0", "0", "0", "0", "0", "nan"), "fgcal fk", "q"),
    ("fk_q_huge", _argv("fk", "abb_irb120", "0", "0", "0", "0", "0", "1e400"), "fgcal fk", "q"),
    ("fk_q_count", _argv("fk", "abb_irb120", "0", "0"), "", "6 joints"),
    ("fk_q_outside_limits", _argv("fk", "abb_irb120", "0", "0", "0", "0", "0", "90"), "q6", "--deg"),
    ("fk_tip_on_yaml_robot", _argv("fk", "robot.yaml", "--tip", "tool0", "0", "0", "0", "0", "0", "0"), "robot.yaml",
     "URDF"),
    ("bench_sizes_small", _argv("bench", "--sizes", "5"), "fgcal bench", "--sizes"),
    ("bench_repeats_zero", _argv("bench", "--repeats", "0"), "fgcal bench", "--repeats"),
    ("bench_faro_missing", _argv("bench", "--faro", "nowhere", "--sizes", "20"), "nowhere", "dataset.yaml"),
    ("demo_n_zero", _argv("demo", "--n", "0"), "fgcal demo", "--n"),
    ("demo_n_huge", _argv("demo", "--n", "50000"), "fgcal demo", "--n"),
    ("demo_out_is_a_file", _argv("demo", "--out", "robot.yaml", "--n", "30"), "robot.yaml", "is a file"),
    # Issue 24: robot programs (fgcal compensate), the calibrated region, the URDF and UR exports
    ("rapid_position_two_numbers", _program("p.mod", RAPID_TARGET.replace("[[1,2,3]", "[[1,2]")), "p.mod", "p1"),
    ("rapid_quaternion_zero", _program("p.mod", RAPID_TARGET.replace("[1,0,0,0]", "[0,0,0,0]")), "p.mod", "p1"),
    ("rapid_nan", _program("p.mod", RAPID_TARGET.replace("[[1,2,3]", "[[1,nan,3]")), "p.mod", "p1"),
    ("rapid_unterminated", _program("p.mod", RAPID_TARGET.replace("]];", "]")), "p.mod", "line"),
    ("rapid_undeclared_tool", _program("p.mod", RAPID_TARGET + "PROC main()\n MoveL p1, v100, fine, gun;\nENDPROC\n"),
     "p.mod", "tool 'gun'"),
    ("rapid_no_targets", _program("p.mod", "MODULE M\nENDMODULE\n"), "p.mod", "no targets"),
    ("rapid_out_not_a_program", _program("p.mod", RAPID_TARGET, out="o.csv"), "o.csv", "--out"),
    ("rapid_tool_unknown_name", _program("p.mod", RAPID_TARGET, extra=["--tool", "gun"]), "p.mod", "--tool"),
    ("rapid_tool_five_numbers", _program("p.mod", RAPID_TARGET, extra=["--tool", "0", "0", "1", "0", "0"]), "p.mod",
     "--tool"),
    ("krl_missing_x", _program("p.dat", "DEFDAT P\nDECL E6POS XP1={Y 2,Z 3,A 0,B 0,C 0}\nENDDAT\n", out="o.dat"),
     "p.dat", "X"),
    ("krl_out_rapid", _program("p.dat", "DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\nENDDAT\n"), "o.mod",
     "--out"),
    ("program_with_tcp", _program("p.mod", RAPID_TARGET, extra=["--tcp", "0", "0", "0.1"]), "p.mod", "--tcp"),
    # Issue 43: declarations held in another file
    ("declarations_missing", _program("p.mod", RAPID_TARGET, extra=["--declarations", "user.sys"]), "user.sys",
     "not found"),
    ("declarations_none_in_file", _prepare_then(lambda root: ((root / "user.sys").write_text("MODULE U\nENDMODULE\n"),
     (root / "p.mod").write_text(RAPID_TARGET + "ENDMODULE\n")), ["compensate", "abb_irb120", "p.mod", "--out", "o.mod",
     "--declarations", "user.sys"]), "user.sys", "declares no tool"),
    ("declarations_krl_for_rapid", _prepare_then(lambda root: ((root / "c.dat").write_text("TOOL_DATA[1]={X 0}\n"),
     (root / "p.mod").write_text(RAPID_TARGET + "ENDMODULE\n")), ["compensate", "abb_irb120", "p.mod", "--out", "o.mod",
     "--declarations", "c.dat"]), "c.dat", "RAPID modules"),
    ("declarations_tool_data_short", _prepare_then(lambda root: (
     (root / "c.dat").write_text("DEFDAT $CONFIG\nTOOL_DATA[1]={X 0,Y 0,Z 100}\nENDDAT\n"),
     (root / "p.dat").write_text("DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\nENDDAT\n")),
     ["compensate", "abb_irb120", "p.dat", "--out", "o.dat", "--declarations", "c.dat"]), "line 2, TOOL_DATA[1]",
     "missing A, B, C"),
    ("declarations_load_nan", _prepare_then(lambda root: (
     (root / "c.dat").write_text("TOOL_DATA[1]={X 0,Y 0,Z 1,A 0,B 0,C 0}\nLOAD_DATA[1]={M nan,CM {X 0},J {X 0}}\n"),
     (root / "p.dat").write_text("DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\nENDDAT\n")),
     ["compensate", "abb_irb120", "p.dat", "--out", "o.dat", "--declarations", "c.dat"]), "LOAD_DATA[1]", "M"),
    ("declarations_tool_data_twice", _prepare_then(lambda root: (
     (root / "c.dat").write_text("TOOL_DATA[1]={X 0,Y 0,Z 1,A 0,B 0,C 0}\nTOOL_DATA[1]={X 0,Y 0,Z 2,A 0,B 0,C 0}\n"),
     (root / "p.dat").write_text("DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\nENDDAT\n")),
     ["compensate", "abb_irb120", "p.dat", "--out", "o.dat", "--declarations", "c.dat"]), "line 2, TOOL_DATA[1]",
     "given twice"),
    ("krl_angle_beyond_a_turn", _program("p.dat", "DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 6e5,B 0,C 0}\nENDDAT\n",
     out="o.dat"), "XP1", "beyond a turn"),
    ("declarations_on_a_csv", _argv("compensate", "robot.yaml", "targets.csv", "--out", "o.csv", "--declarations",
     "u.sys"), "--declarations", "RAPID"),
    ("krl_fdat_tool_undeclared", _program("p.dat", "DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\n"
     "DECL FDAT FP1={TOOL_NO 2,BASE_NO 0}\nENDDAT\n", out="o.dat"), "XP1", "--declarations"),
    ("krl_fdat_external_tcp", _program("p.dat", "DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0}\n"
     "DECL FDAT FP1={TOOL_NO 0,BASE_NO 0,IPO_FRAME #TCP}\nENDDAT\n", out="o.dat"), "XP1", "IPO_FRAME #TCP"),
    ("csv_tool_option", _argv("compensate", "robot.yaml", "targets.csv", "--out", "o.csv", "--tool", "t"), "--tool",
     "RAPID"),
    ("csv_abc_without_orientation", _prepare_then(
        lambda root: (root / "abc.csv").write_text("target,x,y,z,a,b,c\nt,0.4,0,0.5,0,90,0\n"),
        ["compensate", "robot.yaml", "abc.csv", "--out", "o.csv"]), "abc.csv", "--orientation abc"),
    ("csv_quaternion_not_unit", _prepare_then(
        lambda root: (root / "q.csv").write_text("target,x,y,z,qw,qx,qy,qz\nt,0.4,0,0.5,2,0,0,0\n"),
        ["compensate", "robot.yaml", "q.csv", "--out", "o.csv", "--orientation", "quaternion"]), "q.csv", "norm"),
    ("region_short_row", _robot_edit("calibrated_region: [[0, 0]]"), "robot.yaml", "calibrated_region[0]"),
    ("region_nan", _robot_edit("calibrated_region: [[0, 0, 0, 0, 0, .nan]]"), "robot.yaml", "calibrated_region[0]"),
    ("region_not_a_list", _robot_edit("calibrated_region: 5"), "robot.yaml", "calibrated_region"),
    ("urdf_origin_not_urdf", _robot_edit("urdf: {file: arm.yaml, tip: tool0}"), "robot.yaml", "urdf.file"),
    ("export_template_other_robot", _argv("export", "robot.yaml", "--urdf", "x.urdf", "--template", "good.urdf"),
     "good.urdf", "is not the URDF"),
    ("export_ur_not_a_ur_arm", _argv("export", "seven_axis", "--ur-kinematics", "k.yaml"), "--ur-kinematics",
     "UR arm"),
    ("export_ur_not_yaml", _argv("export", "ur10e", "--ur-kinematics", "k.txt"), "k.txt", ".yaml"),
    ("export_nothing_to_write", _argv("export", "ur10e"), "fgcal export", "--urdf"),
    # From the hunt of issue 24's surfaces
    ("rapid_comment_in_number", _program("p.mod", RAPID_TARGET.replace("[[1,2,3]", "[[- !c\n1,2,3]")), "p.mod",
     "not a plain number"),
    ("rapid_nested_deep", _program("p.mod", "MODULE M\nCONST robtarget p:=" + "[" * 5000 + "1" + "]" * 5000 + ";\n"),
     "p.mod", "nested too deeply"),
    ("rapid_tload_huge", _program("p.mod", RAPID_TOOL.replace("[0.5,", "[1e300,")), "p.mod", "tload"),
    ("rapid_tload_negative", _program("p.mod", RAPID_TOOL.replace("[0.5,", "[-5,")), "p.mod", "tload"),
    ("rapid_wobj_robot_held", _program("p.mod", RAPID_WOBJ.replace("[FALSE,TRUE", "[TRUE,TRUE")), "p.mod",
     "robhold TRUE"),
    ("rapid_cr_only", _program("p.mod", RAPID_TARGET.replace("\n", "\r") + "ENDMODULE\r"), "p.mod", "CR alone"),
    ("rapid_fullwidth_digit", _program("p.mod", RAPID_TARGET.replace("[[1,2,3]", "[[\uff13,2,3]")), "p.mod", "p1"),
    ("rapid_out_is_input", _program("p.mod", RAPID_TARGET, out="p.mod"), "p.mod", "same file"),
    ("rapid_out_fifo", _prepare_then(lambda root: ((root / "p.mod").write_text(RAPID_TARGET + "ENDMODULE\n"),
     os.mkfifo(root / "o.mod")), ["compensate", "abb_irb120", "p.mod", "--out", "o.mod"]), "o.mod",
     "not a regular file"),
    ("rapid_tool_nan", _program("p.mod", RAPID_TARGET, extra=["--tool", "0", "0", "nan", "0", "0", "0"]), "p.mod",
     "--tool"),
    ("rapid_tool_underscore", _program("p.mod", RAPID_TARGET, extra=["--tool", "0", "0", "1_20", "0", "0", "0"]),
     "p.mod", "--tool"),
    ("rapid_base_huge", _program("p.mod", RAPID_TARGET, extra=["--base", "1e300", "0", "0", "0", "0", "0"]), "p.mod",
     "--base"),
    ("csv_out_is_the_robot", _argv("compensate", "robot.yaml", "targets.csv", "--out", "robot.yaml"), "robot.yaml",
     ".csv"),
    ("csv_out_is_the_targets", _argv("compensate", "robot.yaml", "targets.csv", "--out", "targets.csv"),
     "targets.csv", "same file"),
    ("csv_out_fifo", _prepare_then(lambda root: os.mkfifo(root / "o.csv"),
     ["compensate", "robot.yaml", "targets.csv", "--out", "o.csv"]), "o.csv", "not a regular file"),
    ("csv_column_twice", _prepare_then(lambda root: (root / "d.csv").write_text("target,x,y,z,x\nt,0.4,0,0.5,1\n"),
     ["compensate", "robot.yaml", "d.csv", "--out", "o.csv"]), "d.csv", "given twice"),
    ("csv_empty_target_name", _prepare_then(lambda root: (root / "e.csv").write_text("target,x,y,z\n ,0.4,0,0.5\n"),
     ["compensate", "robot.yaml", "e.csv", "--out", "o.csv"]), "e.csv", "empty target name"),
    ("program_without_suffix", _argv("compensate", "robot.yaml", "nothing", "--out", "o.csv"), "nothing",
     "file not found"),
    ("export_kinematics_over_the_robot", _argv("export", "robot.yaml", "--ur-kinematics", "robot.yaml"), "robot.yaml",
     "same file"),
    ("export_kinematics_over_the_sidecar", _argv("export", "ur10e", "--urdf", "u.urdf", "--ur-kinematics",
     "u.compliance.yaml"), "u.compliance.yaml", "same file"),
    ("export_urdf_over_the_template", _argv("export", "good.urdf", "--urdf", "good.urdf"), "good.urdf", "same file"),
    ("export_urdf_fifo", _prepare_then(lambda root: os.mkfifo(root / "f.urdf"),
     ["export", "ur10e", "--urdf", "f.urdf"]), "f.urdf", "not a regular file"),
    ("program_with_csv_units", _program("p.mod", RAPID_TARGET, extra=["--length-unit", "mm"]), "p.mod",
     "--length-unit"),
    ("rapid_cfx_nine", _program("p.mod", RAPID_TARGET.replace("[0,0,0,0],[9E9", "[0,0,0,9],[9E9")), "p.mod",
     "cfx 9"),
    ("export_nominal_alone", _argv("export", "ur10e", "--urdf", "u.urdf", "--nominal", "abb_irb120"), "fgcal export",
     "--nominal"),
    ("region_outside_limits", _robot_edit("calibrated_region: [[0, 0, 0, 0, 0, 900]]"), "robot.yaml",
     "outside the joint limits"),
    # The motion history (issue 25): cells, plans, targets and configs.
    ("cell_lost_motion_huge", _prepare_then(_text("lm.yaml", LOST_MOTION_CELL.replace("[0.03, 0.02,", "[30, 0.02,")),
     ["simulate", "lm.yaml", "--out", "o"]), "lm.yaml", "motion_history.lost_motion"),
    ("cell_lost_motion_five_joints", _prepare_then(_text("lm.yaml", LOST_MOTION_CELL.replace("0.015, 0.02]", "0.015]")),
     ["simulate", "lm.yaml", "--out", "o"]), "lm.yaml", "motion_history.lost_motion"),
    ("cell_lost_motion_bad_approach", _prepare_then(_text("lm.yaml", LOST_MOTION_CELL.replace(
     "approach: previous", "approach: sideways")), ["simulate", "lm.yaml", "--out", "o"]), "lm.yaml",
     "motion_history.approach"),
    ("plan_approach_offset_zero", _argv("plan", "irb120_tracker", "--n", "5", "--out", "p", "--approach",
     "unidirectional", "--approach-offset", "0"), "--approach-offset", ""),
    ("csv_approach_partial", _prepare_then(_text("a.csv", "target,x,y,z," + ",".join(f"before_q{i}" for i in
     range(1, 7)) + "\nt,0.4,0,0.5,0.1,,,,,\n"), ["compensate", "robot.yaml", "a.csv", "--out", "o.csv"]),
     "a.csv", "line 2"),
    ("csv_speed_zero", _prepare_then(_text("s.csv", "target,x,y,z,speed\nt,0.4,0,0.5,0\n"),
     ["compensate", "robot.yaml", "s.csv", "--out", "o.csv"]), "s.csv", "column speed"),
    ("config_residual_model_unknown", _prepare_then(_text("c.yaml", "dataset: data\nresidual_model: magic\n"),
     ["calibrate", "c.yaml", "--out", "out", "--no-plots"]), "c.yaml", "residual_model"),
    ("config_complement_with_nothing_held_out", _prepare_then(_text("c.yaml", "dataset: data\nformulation: tracker"
     "\nvalidation: {holdout: 0, complement: true}\n"), ["calibrate", "c.yaml", "--out", "out", "--no-plots"]),
     "c.yaml", "validation.complement"),
    ("config_residual_model_of_pairs", _prepare_then(_text("c.yaml", "dataset: data\nformulation: pairs\n"
     "residual_model: gp\n"), ["calibrate", "c.yaml", "--out", "out", "--no-plots"]), "c.yaml", "residual_model"),
    ("robot_model_unknown", _robot_edit("model: DH,h"), "robot.yaml", "model"),
    # Trees (issue 28): tips on joints that exist, named apart from the flange.
    ("robot_tip_on_no_joint", _robot_edit("tips: [{name: t, joint: 99}]"), "robot.yaml", "tips[0].joint"),
    ("robot_tip_named_flange", _robot_edit("tips: [{name: flange, joint: 2}]"), "robot.yaml", "tips"),
    ("robot_flange_on_no_joint", _robot_edit("flange_joint: 9"), "robot.yaml", "flange_joint"),
    ("robot_tips_not_a_list", _robot_edit("tips: 3"), "robot.yaml", "tips"),
    ("region_too_few_for_a_fit", _prepare_then(lambda root: (root / "robot.yaml").write_text(
     (root / "robot.yaml").read_text() + "\ncalibrated_region: [[0, 0, 0, 0, 0, 0]]\n"),
     ["export", "robot.yaml", "--urdf", "r.urdf", "--rigid-fit"]), "--rigid-fit", "distinct configurations"),
]  # fmt: skip


@pytest.mark.parametrize(("damage", "file", "field"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_surfaces(source, tmp_path, capsys, monkeypatch, alarm, damage, file, field):  # noqa: F811
    root = tmp_path / "case"
    shutil.copytree(source, root, symlinks=True)
    monkeypatch.chdir(root)
    argv = damage(root)
    before = {p for p in root.rglob("*") if p.name != "dataset.yaml"}
    status = main(argv)
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert file in error and field in error, error
    if argv[0] == "export":  # refused before either file is written
        assert {p for p in root.rglob("*") if p.name != "dataset.yaml"} == before


def test_the_corpora_hold_two_hundred_cases():
    from test_bad_input import BAD, ODD
    from test_bad_input_corpus import CASES as FIRST
    from test_bad_input_corpus import MEASUREMENT_FILES, SETUPS

    assert len(CASES) + len(FIRST) + len(BAD) + len(ODD) + len(MEASUREMENT_FILES) + len(SETUPS) >= 200
