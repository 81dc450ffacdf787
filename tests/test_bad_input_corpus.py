"""The bad-input corpus: one row per damaged input, every file kind fgcal reads (robot YAML,
cell YAML, dataset.yaml and each CSV table, calibration config, online setup, measurement
files). Each row runs an ``fgcal`` command in-process and expects exit status 2 with one line
naming the file and the field, no traceback, within a bounded time. Measurement files are
different: ``fgcal online`` goes on, and moves a bad file to ``rejected/`` with the reason.
(Checkpoints and log records: tests/test_online_state.py; images: tests/test_images.py;
the numbered defects of issue 13: tests/test_bad_input.py.)"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml
from conftest import REPO, SEED_CELL
from test_bad_input import alarm, set_cell, set_header  # noqa: F401 (alarm is a fixture)

from fgcal.commands.cli import main

ROBOT = REPO / "datasets" / "robots" / "abb_irb120.yaml"
SELFCONTAINED_CELL = REPO / "datasets" / "cells" / "dual_arm_selfcontained.yaml"


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("corpus_source")
    simulate(SEED_CELL, out / "data", seed=5)
    return out


def _edit_yaml(path: Path, change: Callable[[dict], None]) -> None:
    doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    change(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")


def _text(path_name: str, text: str):
    def apply(root: Path) -> None:
        (root / path_name).write_text(text, encoding="utf-8")

    return apply


def _header(change: Callable[[dict], None]):
    return lambda root: _edit_yaml(root / "data" / "dataset.yaml", change)


def _table(name: str, change: Callable[[list[str]], list[str]]):
    def apply(root: Path) -> None:
        path = root / "data" / name
        lines = path.read_text(encoding="utf-8").splitlines()
        path.write_text("\n".join(change(lines)) + "\n", encoding="utf-8")

    return apply


def _cell(table: str, row: int, column: str, text: str):
    return lambda root: set_cell(table, row, column, text)(root / "data")


def _config(change: Callable[[dict], None]):
    return lambda root: _edit_yaml(root / "calibration.yaml", change)


def _robot(change: Callable[[dict], None]):
    return lambda root: _edit_yaml(root / "robot.yaml", change)


def _joint(i: int, key: str, value):
    def change(doc: dict) -> None:
        doc["joints"][i][key] = value

    return _robot(change)


def _set(path: str, value):
    """A change setting dotted ``path`` of a YAML document (creating mappings on the way)."""

    def change(doc: dict) -> None:
        *parents, last = path.split(".")
        node = doc
        for part in parents:
            node = node.setdefault(part, {})
        node[last] = value

    return change


def _drop(path: str):
    def change(doc: dict) -> None:
        *parents, last = path.split(".")
        node = doc
        for part in parents:
            node = node[part]
        del node[last]

    return change


def _contact(tables: dict[str, str], change: Callable[[dict], None] = lambda doc: None):
    """The seed dataset with contact elements (two balls on the flange, a table plane) and the
    contact tables ``tables`` (name -> CSV text), its header then changed by ``change``."""

    def apply(root: Path) -> None:
        doc = yaml.safe_load((root / "data" / "dataset.yaml").read_text(encoding="utf-8"))
        doc["contact"] = {
            "elements": {"a": {"tip": "flange", "xyz": [0, 0, 0.05], "radius": 0.01},
                         "b": {"tip": "flange", "xyz": [0, 0.1, 0.05], "radius": 0.01}},
            "planes": {"table": {"normal": [0, 0, 1], "offset": 0.2}},
        }  # fmt: skip
        for name, text in tables.items():
            (root / "data" / f"{name}.csv").write_text(text, encoding="utf-8")
            doc["measured"].append(name)
            doc["files"][name] = f"{name}.csv"
        change(doc)
        (root / "data" / "dataset.yaml").write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")

    return apply


def _truth_without(cell: str, section: str, formulation: str | None = None):
    """A simulation of the bundled ``cell`` in place of the seed's, its truth's ``section`` removed
    (calibrated by ``formulation``, else the dataset's own)."""

    def apply(root: Path) -> None:
        from fgcal.simulation.simulate import simulate

        shutil.rmtree(root / "data")
        simulate(REPO / "datasets" / "cells" / f"{cell}.yaml", root / "data", seed=1)
        _edit_yaml(root / "data" / "truth" / "ground_truth.yaml", lambda doc: doc.pop(section))
        if formulation is not None:
            (root / "calibration.yaml").write_text(f"dataset: data\nformulation: {formulation}\n", encoding="utf-8")

    return apply


CONTACTS = "config,element_a,element_b\nc0000,a,b\nc0001,a,b\n"
PLANE_CONTACTS = "config,element,plane\nc0000,a,table\nc0001,b,table\n"
TIP_DISTANCES = "config,element_a,element_b,distance\nc0000,a,b,0.3\nc0001,a,b,0.31\n"


def _observed(text: str, change: Callable[[dict], None] = lambda doc: None):
    """The seed dataset with a camera on link 3 seeing a board on the flange (self_observation)
    and the observed_pixels table ``text``, its header then changed by ``change``."""

    def apply(root: Path) -> None:
        doc = yaml.safe_load((root / "data" / "dataset.yaml").read_text(encoding="utf-8"))
        doc["self_observation"] = {
            "cameras": {"eye": {"joint": 3, "mounting": {"xyz": [0, 0, 0.1]}, "image_size": [640, 480],
                                "intrinsics": {"fx": 500, "fy": 500, "cx": 320, "cy": 240}}},
            "boards": {"hand": {"tip": "flange", "pose": {"xyz": [0, 0, 0.05]}, "corners": [3, 2], "square": 0.02}},
        }  # fmt: skip
        (root / "data" / "observed_pixels.csv").write_text(text, encoding="utf-8")
        doc["measured"].append("observed_pixels")
        doc["files"]["observed_pixels"] = "observed_pixels.csv"
        change(doc)
        (root / "data" / "dataset.yaml").write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")

    return apply


OBSERVED = "config,camera,board,point,u,v\nc0000,eye,hand,c0000,300,200\nc0000,eye,hand,c0102,340,230\n"


def _cell_file(change: Callable[[dict], None]):
    return lambda root: _edit_yaml(root / "cell.yaml", change)


def _xacro(include: str = "$(find arm_pkg)/macro.xacro", call: str = '<xacro:arm prefix=""/>'):
    """A xacro package ``arm_pkg``: arm.xacro includes macro.xacro (an arm of one joint) and calls it."""

    def apply(root: Path) -> None:
        (root / "arm_pkg").mkdir()
        (root / "arm_pkg" / "macro.xacro").write_text(
            '<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:macro name="arm" params="prefix">'
            '<link name="${prefix}base_link"/><link name="${prefix}tool0"/>'
            '<joint name="${prefix}joint_1" type="revolute"><parent link="${prefix}base_link"/>'
            '<child link="${prefix}tool0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>'
            "</joint></xacro:macro></robot>",
            encoding="utf-8",
        )
        (root / "arm_pkg" / "arm.xacro").write_text(
            f'<robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:include filename="{include}"/>'
            f"{call}</robot>",
            encoding="utf-8",
        )

    return apply


XACRO_FK = ["fk", "arm_pkg/arm.xacro", "0"]
TWO_LOADS = (
    "MODULE M\nPERS tooldata a:=[TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,30],[1,0,0,0],0,0,0]];\n"
    "PERS tooldata b:=[TRUE,[[0,0,100],[1,0,0,0]],[2,[0,0,30],[1,0,0,0],0,0,0]];\n"
    "CONST robtarget p1:=[[400,0,500],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
    "CONST robtarget p2:=[[400,50,500],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\n"
    "PROC main()\n  MoveL p1, v100, fine, a;\n  MoveL p2, v100, fine, b;\nENDPROC\nENDMODULE\n"
)
CALIBRATE = ["calibrate", "calibration.yaml", "--out", "out", "--no-plots"]
FK = ["fk", "robot.yaml", "0", "0", "0", "0", "0", "0"]
SIMULATE = ["simulate", "cell.yaml", "--out", "sim", "--seed", "1"]

# (case id, damage, command, file named, field named)
CASES = [
    # robot YAML (fgcal fk)
    ("robot_malformed", _text("robot.yaml", "name: [unclosed\n"), FK, "robot.yaml", "malformed YAML"),
    ("robot_not_a_mapping", _text("robot.yaml", "- 1\n- 2\n"), FK, "robot.yaml", ""),
    ("robot_no_joints", _robot(_drop("joints")), FK, "robot.yaml", "joints"),
    ("robot_joint_nan", _joint(2, "alpha", float("nan")), FK, "robot.yaml", "joints[2].alpha"),
    ("robot_joint_text", _joint(1, "d", "long"), FK, "robot.yaml", "joints[1].d"),
    ("robot_limits_short", _joint(0, "limits", [-1]), FK, "robot.yaml", "joints[0].limits"),
    ("robot_mass_negative", _joint(3, "mass", -2.0), FK, "robot.yaml", "joints[3].mass"),
    ("robot_com_wrong_length", _joint(4, "com", [0, 1]), FK, "robot.yaml", "joints[4].com"),
    ("robot_unknown_key", _robot(_set("colour", "orange")), FK, "robot.yaml", "colour"),
    ("robot_unknown_units", _robot(_set("units.length", "furlong")), FK, "robot.yaml", "units"),
    ("robot_gravity_short", _robot(_set("gravity", [0, -9.81])), FK, "robot.yaml", "gravity"),
    ("robot_huge_length", _joint(0, "d", 1e300), FK, "robot.yaml", "joints[0].d"),
    # joint speed and effort limits, which fgcal export writes to URDF (issue 43, item 2)
    ("robot_velocity_negative", _joint(1, "velocity", -3), FK, "robot.yaml", "joints[1].velocity"),
    ("robot_velocity_nan", _joint(1, "velocity", float("nan")), FK, "robot.yaml", "joints[1].velocity"),
    ("robot_effort_text", _joint(2, "effort", "strong"), FK, "robot.yaml", "joints[2].effort"),
    ("robot_effort_huge", _joint(2, "effort", 1e300), FK, "robot.yaml", "joints[2].effort"),
    # names fgcal export writes into a URDF (issue 43, item 6)
    ("robot_flange_name_empty", _robot(_set("flange_name", "")), FK, "robot.yaml", "flange_name"),
    ("robot_tip_name_not_xml", _robot(_set("tips", [{"name": "a\ufffe", "joint": 2}])), FK, "robot.yaml", "tips"),
    ("robot_name_not_xml", _robot(_set("name", "arm\uffff")), FK, "robot.yaml", "name"),
    # issue 40: fixed frames, compliances about the parent and coupled, tip payloads, fixed bodies
    ("robot_frame_name", _joint(2, "frame", {"name": "my mount"}), FK, "robot.yaml", "joints[2].frame.name"),
    ("robot_frame_rpy_short", _joint(1, "frame", {"name": "m", "rpy": [0, 0]}), FK, "robot.yaml",
     "joints[1].frame.rpy"),
    ("robot_frame_twice",
     lambda root: (_joint(1, "frame", {"name": "m"})(root), _joint(3, "frame", {"name": "m"})(root)), FK, "robot.yaml",
     "joints[3].frame.name"),
    ("robot_frame_no_name", _joint(1, "frame", {"xyz": [0, 0, 1]}), FK, "robot.yaml", "joints[1].frame.name"),
    ("robot_compliance_about", _joint(2, "compliance", {"about": "child"}), FK, "robot.yaml",
     "joints[2].compliance.about"),
    ("robot_coupled_from_itself", _joint(2, "compliance", {"coupled_from": 3}), FK, "robot.yaml",
     "joints[2].compliance.coupled_from"),
    ("robot_coupled_from_beyond", _joint(2, "compliance", {"coupled_from": 40}), FK, "robot.yaml",
     "joints[2].compliance.coupled_from"),
    # a coupled compliance between joints that are not parallel (the wrist's roll against the elbow's pitch)
    ("robot_coupled_unparallel", _joint(3, "compliance", {"coupled_from": 3}), FK, "robot.yaml",
     "joints[3].compliance.coupled_from"),
    ("robot_tip_payload_negative", _robot(_set("tips", [{"name": "hand", "joint": 6, "payload": {"mass": -2}}])), FK,
     "robot.yaml", "tips[0].payload.mass"),
    ("robot_tip_payload_unknown_key", _robot(_set("tips", [{"name": "hand", "joint": 6, "payload": {"weight": 2}}])),
     FK, "robot.yaml", "tips[0].payload.weight"),
    ("robot_tip_calibrate_name", _robot(_set("tips", [{"name": "my hand", "joint": 6, "calibrate": True}])), FK,
     "robot.yaml", "tips[0].calibrate"),
    ("robot_body_mass_negative", _robot(_set("bodies", [{"name": "head", "joint": 2, "mass": -1}])), FK, "robot.yaml",
     "bodies[0].mass"),
    ("robot_body_joint_beyond", _robot(_set("bodies", [{"name": "head", "joint": 40, "mass": 1, "com": [0, 0, 0]}])),
     FK, "robot.yaml", "bodies[0].joint"),
    ("robot_body_no_mass", _robot(_set("bodies", [{"name": "head", "joint": 2}])), FK, "robot.yaml", "bodies[0].mass"),
    ("robot_body_no_com", _robot(_set("bodies", [{"name": "head", "joint": 2, "mass": 1}])), FK, "robot.yaml",
     "bodies[0].com"),
    ("robot_tip_payload_no_com", _robot(_set("tips", [{"name": "hand", "joint": 6, "payload": {"mass": 2}}])), FK,
     "robot.yaml", "tips[0].payload.com"),
    # a vendor's xacro (issue 43, item 3): fgcal fk and export expand it; what xacro refuses names the file
    ("xacro_package_missing", _xacro(), [*XACRO_FK, "--package", "arm_pkg=no_such_folder"], "no_such_folder",
     "--package"),
    ("xacro_find_unknown_package", _xacro(include="$(find other_pkg)/m.xacro"), XACRO_FK, "arm.xacro", "other_pkg"),
    ("xacro_unknown_macro", _xacro(call="<xacro:no_such_arm/>"), XACRO_FK, "arm.xacro", "xacro failed"),
    ("xacro_undefined_property", _xacro(call='<link name="${missing}"/>'), XACRO_FK, "arm.xacro", "xacro failed"),
    ("xacro_malformed", _xacro(call="<link"), XACRO_FK, "arm.xacro", "xacro failed"),
    ("xacro_template_fails", _xacro(call="<xacro:no_such_arm/>"),
     ["export", "abb_irb120", "--urdf", "o.urdf", "--template", "arm_pkg/arm.xacro"], "arm.xacro", "xacro failed"),
    # fgcal compensate (issue 43): --tcp in --length-unit, a program corrected already, loads of several tools
    (
        "tcp_beyond_10_m_in_mm",
        _text("t.csv", "target,x,y,z\nt,400,0,500\n"),
        ["compensate", "robot.yaml", "t.csv", "--out", "o.csv", "--length-unit", "mm", "--tcp", "0", "0", "10001"],
        "",
        "--tcp",
    ),
    (
        "program_corrected_already",
        _text(
            "p.mod",
            "MODULE M\n! corrected by fgcal compensate for a controller\n"
            "CONST robtarget p1:=[[400,0,500],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\nENDMODULE\n",
        ),
        ["compensate", "robot.yaml", "p.mod", "--out", "o.mod"],
        "p.mod",
        "line 2",
    ),
    (
        "program_tools_of_two_loads_one_payload_option",
        _text("p.mod", TWO_LOADS),
        ["compensate", "robot.yaml", "p.mod", "--out", "o.mod", "--payload-mass", "2"],
        "p.mod",
        "tooldata",
    ),
    # cell YAML (fgcal simulate)
    ("cell_malformed", _text("cell.yaml", "objects: {a: [1, 2\n"), SIMULATE, "cell.yaml", "malformed YAML"),
    ("cell_unknown_robot", _cell_file(_set("robot", "no_such_robot")), SIMULATE, "cell.yaml", "robot"),
    ("cell_unknown_key", _cell_file(_set("lighting", "dim")), SIMULATE, "cell.yaml", "lighting"),
    ("cell_design_zero", _cell_file(_set("design.n_configurations", 0)), SIMULATE, "cell.yaml", "n_configurations"),
    ("cell_standoff_text", _cell_file(_set("design.standoff", "far")), SIMULATE, "cell.yaml", "standoff"),
    ("cell_fixture_nan", _cell_file(_set("fixture.xyz", [0, float("nan"), 0])), SIMULATE, "cell.yaml", "fixture"),
    # dataset.yaml (fgcal calibrate)
    ("header_malformed", _text("data/dataset.yaml", "format: [\n"), CALIBRATE, "dataset.yaml", "malformed YAML"),
    ("header_wrong_format", _header(_set("format", "other/2")), CALIBRATE, "dataset.yaml", "format"),
    ("header_unknown_key", _header(_set("operator", "me")), CALIBRATE, "dataset.yaml", "operator"),
    ("header_unknown_robot", _header(_set("robot", "robot9000")), CALIBRATE, "dataset.yaml", "robot"),
    ("header_unknown_units", _header(_set("units.length", "inch-ish")), CALIBRATE, "dataset.yaml", "units"),
    ("header_unknown_measured", _header(_set("measured", ["x_rays"])), CALIBRATE, "dataset.yaml", "measured[0]"),
    ("header_no_files", _header(_drop("files")), CALIBRATE, "dataset.yaml", "files"),
    ("header_missing_table", _header(_set("files.camera_points", "nope.csv")), CALIBRATE, "nope.csv", ""),
    (
        "header_camera_fx_nan",
        _header(_set("camera.intrinsics.fx", float("nan"))),
        CALIBRATE,
        "dataset.yaml",
        "camera.intrinsics.fx",
    ),
    (
        "header_camera_size_short",
        _header(_set("camera.image_size", [640])),
        CALIBRATE,
        "dataset.yaml",
        "camera.image_size",
    ),
    ("header_payload_negative", _header(_set("payload.mass", -5)), CALIBRATE, "dataset.yaml", "payload.mass"),
    ("header_fixture_short", _header(_set("fixture.xyz", [0, 0])), CALIBRATE, "dataset.yaml", "fixture.xyz"),
    ("header_targets_not_list", _header(_set("tracker.targets", 3)), CALIBRATE, "dataset.yaml", "tracker.targets"),
    # configurations.csv
    (
        "configs_missing_joint",
        _table("configurations.csv", lambda ls: [",".join(r.split(",")[:-1]) for r in ls]),
        CALIBRATE,
        "configurations.csv",
        "header",
    ),
    (
        "configs_extra_joint",
        _table("configurations.csv", lambda ls: [ls[0] + ",q7"] + [r + ",0" for r in ls[1:]]),
        CALIBRATE,
        "configurations.csv",
        "header",
    ),
    ("configs_empty_file", _table("configurations.csv", lambda ls: []), CALIBRATE, "configurations.csv", ""),
    ("configs_no_rows", _table("configurations.csv", lambda ls: ls[:1]), CALIBRATE, "configurations.csv", ""),
    (
        "configs_duplicate_id",
        _table("configurations.csv", lambda ls: [*ls, ls[1]]),
        CALIBRATE,
        "configurations.csv",
        "config",
    ),
    (
        "configs_ragged_row",
        _table("configurations.csv", lambda ls: [*ls[:2], ls[2] + ",7", *ls[3:]]),
        CALIBRATE,
        "configurations.csv",
        "line 3",
    ),
    ("configs_empty_value", _cell("configurations.csv", 2, "q4", ""), CALIBRATE, "configurations.csv", "column q4"),
    (
        "configs_text_value",
        _cell("configurations.csv", 1, "q1", "ninety"),
        CALIBRATE,
        "configurations.csv",
        "column q1",
    ),
    (
        "configs_comma_decimal",
        _cell("configurations.csv", 1, "q5", '"0,5"'),
        CALIBRATE,
        "configurations.csv",
        "column q5",
    ),
    (
        "configs_no_config_column",
        _table("configurations.csv", lambda ls: [ls[0].replace("config", "id", 1), *ls[1:]]),
        CALIBRATE,
        "configurations.csv",
        "config",
    ),
    # points.csv
    (
        "points_missing_column",
        _table("points.csv", lambda ls: [ls[0].replace(",z", ",zz"), *ls[1:]]),
        CALIBRATE,
        "points.csv",
        "z",
    ),
    ("points_text_value", _cell("points.csv", 3, "y", "north"), CALIBRATE, "points.csv", "column y"),
    ("points_huge_value", _cell("points.csv", 3, "y", "-1e40"), CALIBRATE, "points.csv", "column y"),
    # camera_points.csv
    (
        "camera_points_unknown_config",
        _cell("camera_points.csv", 4, "config", "c9999"),
        CALIBRATE,
        "camera_points.csv",
        "config",
    ),
    (
        "camera_points_unknown_point",
        _cell("camera_points.csv", 4, "point", "Q+q_r99c99"),
        CALIBRATE,
        "camera_points.csv",
        "point",
    ),
    (
        "camera_points_ragged",
        _table("camera_points.csv", lambda ls: [*ls[:3], ls[3] + ",1", *ls[4:]]),
        CALIBRATE,
        "camera_points.csv",
        "line 4",
    ),
    (
        "camera_points_missing_column",
        _table("camera_points.csv", lambda ls: [ls[0].replace(",y,", ",why,"), *ls[1:]]),
        CALIBRATE,
        "camera_points.csv",
        "y",
    ),
    (
        "camera_points_binary",
        lambda root: (root / "data" / "camera_points.csv").write_bytes(b"\xff\xfe\x00\x01"),
        CALIBRATE,
        "camera_points.csv",
        "",
    ),
    # pixels.csv (projection)
    ("pixels_unknown_point", _cell("pixels.csv", 2, "point", "Z+z_nowhere"), CALIBRATE, "pixels.csv", "point"),
    ("pixels_nan", _cell("pixels.csv", 2, "v", "NaN"), CALIBRATE, "pixels.csv", "column v"),
    ("pixels_outside_image", _cell("pixels.csv", 2, "u", "5000"), CALIBRATE, "pixels.csv", "column u"),
    # tracker_points.csv
    (
        "tracker_unknown_config",
        _cell("tracker_points.csv", 2, "config", "c-1"),
        CALIBRATE,
        "tracker_points.csv",
        "config",
    ),
    ("tracker_text_value", _cell("tracker_points.csv", 2, "x", "1.2.3"), CALIBRATE, "tracker_points.csv", "column x"),
    # contacts.csv, plane_contacts.csv, tip_distances.csv and dataset.yaml contact (a robot measuring itself)
    ("contacts_unknown_element", _contact({"contacts": CONTACTS.replace("c0001,a,b", "c0001,a,zz")}), CALIBRATE,
     "contacts.csv", "line 3, column element_b"),
    ("contacts_same_element", _contact({"contacts": CONTACTS.replace("c0001,a,b", "c0001,a,a")}), CALIBRATE,
     "contacts.csv", "line 3"),
    ("contacts_twice", _contact({"contacts": CONTACTS + "c0001,b,a\n"}), CALIBRATE, "contacts.csv", "lines 3 and 4"),
    ("contacts_unknown_config", _contact({"contacts": CONTACTS.replace("c0001", "c-1")}), CALIBRATE, "contacts.csv",
     "config"),
    ("contacts_no_section", _contact({"contacts": CONTACTS}, _drop("contact")), CALIBRATE, "dataset.yaml", "contact"),
    ("contact_unknown_tip", _contact({"contacts": CONTACTS}, _set("contact.elements.a.tip", "elbow")), CALIBRATE,
     "dataset.yaml", "contact.elements.a.tip"),
    ("contact_zero_radius", _contact({"contacts": CONTACTS}, _set("contact.elements.b.radius", 0)), CALIBRATE,
     "dataset.yaml", "contact.elements.b.radius"),
    ("contact_zero_normal",
     _contact({"plane_contacts": PLANE_CONTACTS}, _set("contact.planes.table.normal", [0, 0, 0])), CALIBRATE,
     "dataset.yaml", "contact.planes.table.normal"),
    ("contact_nonunit_normal",
     _contact({"plane_contacts": PLANE_CONTACTS}, _set("contact.planes.table.normal", [0, 0, 2])), CALIBRATE,
     "dataset.yaml", "contact.planes.table.normal"),
    ("cell_plane_nonunit_normal",
     _text("cell.yaml", SELFCONTAINED_CELL.read_text(encoding="utf-8").replace("[0, 0, 1]", "[0, 0, 2]")),
     SIMULATE, "cell.yaml", "contact.planes[0].normal"),
    ("plane_contacts_unknown_plane", _contact({"plane_contacts": PLANE_CONTACTS.replace("b,table", "b,wall")}),
     CALIBRATE, "plane_contacts.csv", "line 3, column plane"),
    ("plane_contacts_unknown_element", _contact({"plane_contacts": PLANE_CONTACTS.replace("b,table", "z,table")}),
     CALIBRATE, "plane_contacts.csv", "line 3, column element"),
    ("plane_contacts_no_column", _contact({"plane_contacts": PLANE_CONTACTS.replace("plane\n", "surface\n")}),
     CALIBRATE, "plane_contacts.csv", "plane"),
    ("tip_distances_negative", _contact({"tip_distances": TIP_DISTANCES.replace("0.31", "-0.31")}), CALIBRATE,
     "tip_distances.csv", "line 3, column distance"),
    ("tip_distances_text", _contact({"tip_distances": TIP_DISTANCES.replace("0.31", "far")}), CALIBRATE,
     "tip_distances.csv", "column distance"),
    ("tip_distances_same_element", _contact({"tip_distances": TIP_DISTANCES.replace("c0001,a,b", "c0001,b,b")}),
     CALIBRATE, "tip_distances.csv", "line 3"),
    # truth/ground_truth.yaml of a simulation (scored by fgcal calibrate): a section the score needs removed
    ("truth_without_ballbar", _truth_without("irb120_ballbar", "ballbar"), CALIBRATE, "ground_truth.yaml",
     "ballbar.ball"),
    ("truth_without_touch_probe", _truth_without("seven_axis_touch", "touch_probe"), CALIBRATE,
     "ground_truth.yaml", "touch_probe"),
    ("truth_without_static_camera", _truth_without("irb120_static_camera", "static_camera"), CALIBRATE,
     "ground_truth.yaml", "static_camera.pose"),
    ("truth_without_tracker_probe", _truth_without("irb120_tracker6d", "tracker_probe", "poses"), CALIBRATE,
     "ground_truth.yaml", "tracker_probe"),
    # observed_pixels.csv and dataset.yaml self_observation (cameras on a link seeing boards on the tips)
    ("observed_unknown_camera", _observed(OBSERVED.replace("c0000,eye,hand,c0102", "c0000,nose,hand,c0102")),
     CALIBRATE, "observed_pixels.csv", "line 3, column camera"),
    ("observed_unknown_board", _observed(OBSERVED.replace("eye,hand,c0102", "eye,foot,c0102")), CALIBRATE,
     "observed_pixels.csv", "line 3, column board"),
    ("observed_unknown_point", _observed(OBSERVED.replace("c0102", "c0909")), CALIBRATE, "observed_pixels.csv",
     "line 3, column point"),
    ("observed_text_pixel", _observed(OBSERVED.replace("340", "3x4")), CALIBRATE, "observed_pixels.csv",
     "column u"),
    ("observed_outside_image", _observed(OBSERVED.replace("340,230", "5000,230")), CALIBRATE, "observed_pixels.csv",
     "line 3, column u"),
    ("observed_negative_v", _observed(OBSERVED.replace("340,230", "340,-3")), CALIBRATE, "observed_pixels.csv",
     "line 3, column v"),
    ("observed_no_section", _observed(OBSERVED, _drop("self_observation")), CALIBRATE, "dataset.yaml",
     "self_observation"),
    ("observed_camera_joint", _observed(OBSERVED, _set("self_observation.cameras.eye.joint", 9)), CALIBRATE,
     "dataset.yaml", "self_observation.cameras.eye.joint"),
    ("observed_board_tip", _observed(OBSERVED, _set("self_observation.boards.hand.tip", "elbow")), CALIBRATE,
     "dataset.yaml", "self_observation.boards.hand.tip"),
    ("observed_board_corners", _observed(OBSERVED, _set("self_observation.boards.hand.corners", [1, 2])), CALIBRATE,
     "dataset.yaml", "self_observation.boards.hand.corners"),
    ("observed_camera_named_as_tip", _observed(OBSERVED, lambda doc: doc["self_observation"]["cameras"].update(
        flange=doc["self_observation"]["cameras"]["eye"])), CALIBRATE, "dataset.yaml", "self_observation.cameras"),
    # calibration config
    (
        "config_malformed",
        _text("calibration.yaml", "dataset: data\nnoise: {\n"),
        CALIBRATE,
        "calibration.yaml",
        "malformed YAML",
    ),
    ("config_not_a_mapping", _text("calibration.yaml", "just text\n"), CALIBRATE, "calibration.yaml", ""),
    ("config_unknown_key", _config(_set("speed", "fast")), CALIBRATE, "calibration.yaml", "speed"),
    ("config_stage_unknown_frame", _config(_set("stages", [["theta", "frame.mount.tx"]])), CALIBRATE,
     "calibration.yaml", "stages"),
    ("config_stage_frame_name", _config(_set("stages", [["frame.my mount.tx"]])), CALIBRATE, "calibration.yaml",
     "stages[0][0]"),
    ("config_missing_dataset_dir", _config(_set("dataset", "gone")), CALIBRATE, "gone", ""),
    ("config_formulation", _config(_set("formulation", "sonar")), CALIBRATE, "calibration.yaml", "formulation"),
    ("config_model", _config(_set("model", "DH,q")), CALIBRATE, "calibration.yaml", "model"),
    # null is a value: refused where a field does not document it, never read as the default
    ("config_model_null", _config(_set("model", None)), CALIBRATE, "calibration.yaml", "model"),
    ("config_holdout_null", _config(_set("validation.holdout", None)), CALIBRATE, "calibration.yaml",
     "validation.holdout"),
    ("config_bounds_unknown", _config(_set("bounds.warp", 1.0)), CALIBRATE, "calibration.yaml", "bounds.warp"),
    # a null section is no "off": robust: null kept the Huber loss (an engineer's trial)
    ("config_robust_null", _config(_set("robust", None)), CALIBRATE, "calibration.yaml", "robust"),
    ("config_missing_dataset_named", _config(_set("dataset", "nowhere")), CALIBRATE, "calibration.yaml", "dataset"),
    ("config_bounds_parameter", _config(_set("bounds.alpha9", 1.0)), CALIBRATE, "calibration.yaml", "bounds.alpha9"),
    ("config_bounds_negative", _config(_set("bounds.kz", -1.0)), CALIBRATE, "calibration.yaml", "bounds.kz"),
    (
        "config_compliant_joint_9",
        _config(_set("compliant_joints", [9])),
        CALIBRATE,
        "calibration.yaml",
        "compliant_joints",
    ),
    (
        "config_compliant_joint_text",
        _config(_set("compliant_joints", ["two"])),
        CALIBRATE,
        "calibration.yaml",
        "compliant_joints",
    ),
    ("config_stage_kind", _config(_set("stages", [["theta", "warp"]])), CALIBRATE, "calibration.yaml", "stages[0]"),
    ("config_stage_empty", _config(_set("stages", [[]])), CALIBRATE, "calibration.yaml", "stages[0]"),
    # several measurement sets (sets:)
    ("config_sets_empty", _config(_set("sets", [])), CALIBRATE, "calibration.yaml", "sets"),
    ("config_sets_not_a_list", _config(_set("sets", "pairs")), CALIBRATE, "calibration.yaml", "sets"),
    ("config_sets_no_name", _config(_set("sets", [{"formulation": "pairs"}])), CALIBRATE, "calibration.yaml",
     "sets[0].name"),
    ("config_sets_bad_name", _config(_set("sets", [{"name": "a b", "formulation": "pairs"}])), CALIBRATE,
     "calibration.yaml", "sets[0].name"),
    ("config_sets_formulation", _config(_set("sets", [{"name": "a", "formulation": "sonar"}])), CALIBRATE,
     "calibration.yaml", "sets[0].formulation"),
    ("config_sets_use", _config(_set("sets", [{"name": "a", "formulation": "pairs", "use": "both"}])), CALIBRATE,
     "calibration.yaml", "sets[0].use"),
    ("config_sets_unknown_key", _config(_set("sets", [{"name": "a", "formulation": "pairs", "speed": 1}])),
     CALIBRATE, "calibration.yaml", "sets[0].speed"),
    ("config_sets_twice", _config(_set("sets", [{"name": "a", "formulation": "pairs"},
                                                {"name": "a", "formulation": "projection"}])),
     CALIBRATE, "calibration.yaml", "sets[1].name"),
    ("config_sets_same_table", _config(_set("sets", [{"name": "a", "formulation": "pairs"},
                                                     {"name": "b", "formulation": "pairs"}])),
     CALIBRATE, "calibration.yaml", "sets[1].formulation"),
    ("config_sets_none_fitted", _config(_set("sets", [{"name": "a", "formulation": "pairs", "use": "validation"}])),
     CALIBRATE, "calibration.yaml", "sets"),
    ("config_sets_table_missing", _config(_set("sets", [{"name": "a", "formulation": "pairs"},
                                                        {"name": "t", "formulation": "touch"}])),
     CALIBRATE, "calibration.yaml", "sets[1].formulation"),
    ("config_sets_with_formulation", _config(lambda d: d.update(formulation="pairs", sets=[
        {"name": "a", "formulation": "pairs"}])), CALIBRATE, "calibration.yaml", "formulation"),
    ("config_sets_with_noise", _config(lambda d: d.update(noise={"pixel_sigma_px": 0.5}, sets=[
        {"name": "a", "formulation": "pairs"}])), CALIBRATE, "calibration.yaml", "noise"),
    ("config_sets_noise_negative", _config(_set("sets", [{"name": "a", "formulation": "pairs",
                                                          "noise": {"camera_point_sigma": -1}}])),
     CALIBRATE, "calibration.yaml", "sets[0].noise.camera_point_sigma"),
    ("config_sets_noise_unread", _config(_set("sets", [{"name": "a", "formulation": "pairs",
                                                        "noise": {"tracker_sigma": 1e-5}}])),
     CALIBRATE, "calibration.yaml", "sets[0].noise.tracker_sigma"),
    ("config_sets_robust_kind", _config(_set("sets", [{"name": "a", "formulation": "pairs",
                                                       "robust": {"pixels": ["tukey", 2]}}])),
     CALIBRATE, "calibration.yaml", "sets[0].robust.pixels"),
    (
        "config_noise_negative",
        _config(_set("noise.camera_point_sigma", -1e-4)),
        CALIBRATE,
        "calibration.yaml",
        "noise.camera_point_sigma",
    ),
    (
        "config_noise_zero",
        _config(_set("noise.pixel_sigma_px", 0)),
        CALIBRATE,
        "calibration.yaml",
        "noise.pixel_sigma_px",
    ),
    (
        "config_robust_kind",
        _config(_set("robust.pixels", ["tukey", 2])),
        CALIBRATE,
        "calibration.yaml",
        "robust.pixels",
    ),
    (
        "config_robust_threshold",
        _config(_set("robust.tracker_points", ["huber", -3])),
        CALIBRATE,
        "calibration.yaml",
        "robust.tracker_points",
    ),
    (
        "config_holdout_high",
        _config(_set("validation.holdout", 0.95)),
        CALIBRATE,
        "calibration.yaml",
        "validation.holdout",
    ),
    (
        "config_holdout_text",
        _config(_set("validation.holdout", "a quarter")),
        CALIBRATE,
        "calibration.yaml",
        "validation.holdout",
    ),
    (
        "config_group_images_zero",
        _config(_set("pairs.group_images", 0)),
        CALIBRATE,
        "calibration.yaml",
        "pairs.group_images",
    ),
    ("config_partner", _config(_set("pairs.partner", "neighbour")), CALIBRATE, "calibration.yaml", "pairs.partner"),
    ("config_solver_method", _config(_set("solver.method", "newton")), CALIBRATE, "calibration.yaml", "solver.method"),
    (
        "config_max_iterations_zero",
        _config(_set("solver.max_iterations", 0)),
        CALIBRATE,
        "calibration.yaml",
        "solver.max_iterations",
    ),
    ("config_units", _config(_set("units.length", "parsec-ish")), CALIBRATE, "calibration.yaml", "units"),
    (
        "config_intrinsics_estimate_text",
        _config(_set("intrinsics.estimate", "yes please")),
        CALIBRATE,
        "calibration.yaml",
        "intrinsics.estimate",
    ),
    (
        "config_min_information",
        _config(_set("identifiability.min_information", -1)),
        CALIBRATE,
        "calibration.yaml",
        "identifiability.min_information",
    ),
    ("config_pixels_from", _config(_set("pixels_from", "dreams")), CALIBRATE, "calibration.yaml", "pixels_from"),
    (
        "config_projection_without_camera",
        lambda root: (_header(_drop("camera"))(root), _config(_set("formulation", "projection"))(root)),
        CALIBRATE,
        "dataset.yaml",
        "measured",
    ),
]


def _prepare(source: Path, tmp_path: Path) -> Path:
    root = tmp_path / "case"
    shutil.copytree(source, root)
    shutil.copy(ROBOT, root / "robot.yaml")
    shutil.copy(SEED_CELL, root / "cell.yaml")
    (root / "calibration.yaml").write_text("dataset: data\n", encoding="utf-8")
    return root


@pytest.mark.parametrize(("damage", "command", "file", "field"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_corpus(source, tmp_path, capsys, monkeypatch, alarm, damage, command, file, field):  # noqa: F811
    root = _prepare(source, tmp_path)
    damage(root)
    monkeypatch.chdir(root)
    status = main(command)
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert file in error and field in error, error


def test_the_corpus_is_large():
    from test_bad_input import BAD, ODD

    assert len(CASES) + len(BAD) + len(ODD) + len(MEASUREMENT_FILES) + len(SETUPS) >= 80


# Online: bad setup files stop `fgcal online` with exit 2; bad measurement files are rejected.
SETUPS = [
    ("setup_unknown_key", "dataset: data\nmood: calm\n", "mood"),
    ("setup_released_unknown", "dataset: data\nreleased: [theta2, zz9]\n", "released"),
    ("setup_released_text", "dataset: data\nreleased: theta2\n", "released"),
    ("setup_settings_unknown", "dataset: data\nsettings: {window: 3}\n", "settings"),
    ("setup_window_small", "dataset: data\nsettings: {window_images: 3}\n", "window_images"),
    ("setup_target_negative", "dataset: data\ntarget_accuracy_m: -1\n", "target_accuracy_m"),
    ("setup_malformed", "dataset: [\n", "malformed YAML"),
]


@pytest.mark.parametrize(("text", "field"), [c[1:] for c in SETUPS], ids=[c[0] for c in SETUPS])
def test_online_setup_corpus(source, tmp_path, capsys, alarm, text, field):  # noqa: F811
    root = _prepare(source, tmp_path)
    (root / "setup.yaml").write_text(text, encoding="utf-8")
    (root / "inbox").mkdir()
    status = main(
        [
            "online",
            "--state",
            str(root / "state"),
            "--inbox",
            str(root / "inbox"),
            "--setup",
            str(root / "setup.yaml"),
            "--once",
        ]
    )
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error, error
    assert "setup.yaml" in error and field in error, error
    assert not (root / "state" / "config.yaml").exists()


GOOD = {"format": "fgcal-measurement/1", "joints": [0.1, -0.2, 0.3, 0.0, 0.5, 0.0]}
MEASUREMENT_FILES = [
    ("measurement_not_json", b"{joints: [1, 2", "not valid JSON"),
    ("measurement_nan_joint", json.dumps({**GOOD, "joints": [0, "NaN", 0, 0, 0, 0]}).encode(), "joints[1]"),
    ("measurement_wrong_joint_count", json.dumps({**GOOD, "joints": [0, 0, 0]}).encode(), "joints"),
    ("measurement_unknown_point", json.dumps({**GOOD, "pixels": {"nowhere": [1, 2]}}).encode(), "pixels.nowhere"),
    ("measurement_pixel_short", json.dumps({**GOOD, "pixels": {"P": [1]}}).encode(), "pixels"),
    ("measurement_unknown_unit", json.dumps({**GOOD, "units": {"angle": "gradian"}, "pixels": {}}).encode(), "units"),
    ("measurement_deeply_nested", b"[" * 100000 + b"]" * 100000, "nested too deeply"),
    ("measurement_too_large", b" " * (2 << 20) + b"{}", "larger than"),
    ("measurement_cycle_negative", json.dumps({**GOOD, "cycle": -1, "pixels": {"P": [1, 2]}}).encode(), "cycle"),
    (
        "measurement_joint_as_text",
        json.dumps({**GOOD, "joints": ["0.1", 0, 0, 0, 0, 0], "pixels": {"P": [1, 2]}}).encode(),
        "joints[0]",
    ),
    (
        "measurement_joint_outside_limits",
        json.dumps({**GOOD, "joints": [0, 0, 0, 0, 100, 0], "pixels": {"P": [1, 2]}}).encode(),
        "outside the joint's limits",
    ),
    ("measurement_unknown_key", json.dumps({**GOOD, "exposure": 3, "pixels": {"P": [1, 2]}}).encode(), "exposure"),
]


@pytest.mark.parametrize(
    ("content", "reason"), [c[1:] for c in MEASUREMENT_FILES], ids=[c[0] for c in MEASUREMENT_FILES]
)
def test_bad_measurement_files_are_rejected(source, tmp_path, alarm, content, reason):  # noqa: F811
    root = _prepare(source, tmp_path)
    (root / "setup.yaml").write_text("dataset: data\n", encoding="utf-8")
    inbox = root / "inbox"
    inbox.mkdir()
    point = (root / "data" / "points.csv").read_text(encoding="utf-8").splitlines()[1].split(",")[0]
    (inbox / "bad.json").write_bytes(content.replace(b'"P"', json.dumps(point).encode()))
    status = main(
        ["online", "--state", str(root / "state"), "--inbox", str(inbox), "--setup", str(root / "setup.yaml"), "--once"]
    )
    assert status == 0
    assert (root / "state" / "rejected" / "bad.json").exists()
    why = (root / "state" / "rejected" / "bad.json.error.txt").read_text(encoding="utf-8")
    assert reason in why, why
