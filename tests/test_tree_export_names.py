"""A tree's tip names in its exported URDF (issue 43, item 6): a tip named as a link of fgcal's
layout is renamed to a name no other link has, so that every exported URDF reads back (fgcal and
yourdfpy) with each tip where fgcal's model puts it; names a URDF cannot hold (empty, U+FFFE) are
refused where the robot file is read (exit 2, naming the file and field)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
import yourdfpy
from conftest import REPO
from lxml import etree

import fgcal
from fgcal.commands.cli import main

TORSO = REPO / "datasets" / "robots" / "dual_arm_torso.yaml"


def _torso(tmp_path: Path, flange_name: str, tip_name: str) -> Path:
    """The dual-arm torso with its flange and its right hand renamed."""
    doc = yaml.safe_load(TORSO.read_text())
    doc["flange_name"] = flange_name
    doc["tips"][0]["name"] = tip_name
    path = tmp_path / "tree.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    return path


NAMES = [  # (flange, right hand): each a clash with the layout's names before
    ("tool0", "tool0_tip"),
    ("link_1", "link_1_tip"),
    ("base_link", "base_link_tip"),
    ("world", "world_tip2"),
    ("left_hand", "right_hand"),  # the bundled names, for reference
]


@pytest.mark.parametrize(("flange", "tip"), NAMES)
def test_every_exported_tree_reads_back_with_unique_links(tmp_path, capsys, flange, tip):
    robot_file = _torso(tmp_path, flange, tip)
    assert main(["export", str(robot_file), "--urdf", str(tmp_path / "tree.urdf")]) == 0, capsys.readouterr().err
    links = [e.get("name") for e in etree.parse(str(tmp_path / "tree.urdf")).getroot().findall("link")]
    assert len(links) == len(set(links)), sorted(links)
    sidecar = yaml.safe_load((tmp_path / "tree.compliance.yaml").read_text())
    robot = fgcal.load_robot(robot_file)
    assert set(sidecar["tip_links"]) == set(robot.tip_names)
    assert len(set(sidecar["tip_links"].values())) == len(robot.tip_names)
    said = capsys.readouterr().out.splitlines()[-1]  # the links, as the command lists them
    assert all(f" {link}," in said or said.endswith(f" {link}") for link in sidecar["tip_links"].values()), said
    fgcal.load_robot(tmp_path / "tree.urdf")  # fgcal reads it back (the chain to tool0)
    urdf = yourdfpy.URDF.load(str(tmp_path / "tree.urdf"), load_meshes=False, build_collision_scene_graph=False)
    rigid = robot.with_model("DH,s")
    q = np.random.default_rng(3).uniform(rigid.limits[:, 0], rigid.limits[:, 1], (3, rigid.n_joints))
    for row in q:
        values = rigid.geometry_values(row)[0]  # the coupled joint at its value, as the URDF's comment says
        urdf.update_cfg({f"joint_{i + 1}": v for i, v in enumerate(values)})
        for name, link in sidecar["tip_links"].items():
            np.testing.assert_allclose(urdf.get_transform(link, "world"), rigid.fk(row, tip=name), atol=1e-9)


@pytest.mark.parametrize(
    ("flange", "tip", "field"),
    [("", "right_hand", "flange_name"), ("  ", "right_hand", "flange_name"), ("left_hand", "", "tips[0].name"),
     ("left_hand", "right\ufffehand", "tips[0].name"), ("left\uffffhand", "right_hand", "flange_name")],
    ids=["flange_empty", "flange_blank", "tip_empty", "tip_ufffe", "flange_uffff"],
)  # fmt: skip
def test_names_a_urdf_cannot_hold_are_refused(tmp_path, capsys, flange, tip, field):
    robot_file = _torso(tmp_path, flange, tip)
    status = main(["export", str(robot_file), "--urdf", str(tmp_path / "tree.urdf")])
    error = capsys.readouterr().err.strip()
    assert status == 2 and error.startswith("fgcal: error: ") and "\n" not in error, error
    assert "tree.yaml" in error and field in error, error
    assert not (tmp_path / "tree.urdf").exists()
