"""Issue 43, item 3: a vendor's xacro read without ROS, and a DH calibration written into the
vendor's URDF of the same robot (the ROS-Industrial IRB 120 description in ../shared)."""

from __future__ import annotations

import numpy as np
import pytest
import yourdfpy
from conftest import SHARED, random_parameters
from lxml import etree

import fgcal
from fgcal.commands.cli import main
from fgcal.model.robot_io import save_robot

ROS = SHARED / "data" / "ros_abb_irb120"
XACRO = ROS / "abb_irb120_support" / "urdf" / "irb120_3_58.xacro"
needs_ros = pytest.mark.skipif(not XACRO.exists(), reason="../shared/data/ros_abb_irb120 is not present")


def _yourdfpy(path):
    return yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)


def _tool0(urdf, q: np.ndarray, tip: str = "tool0") -> np.ndarray:
    """``tip`` in base_link (the robot's base frame 0) at each configuration, as yourdfpy reads it."""
    out = []
    for row in q:
        urdf.update_cfg(row)
        out.append(urdf.get_transform(tip, "base_link"))
    return np.array(out)


@needs_ros
def test_the_vendor_xacro_is_the_bundled_irb120(capsys):
    """fgcal fk reads the xacro (its $(find) packages given or found beside it): the same FK as
    the bundled DH IRB 120 at random configurations (1e-9 m)."""
    expanded = fgcal.load_robot(XACRO)
    bundled = fgcal.load_robot("abb_irb120")
    q = np.random.default_rng(3).uniform(bundled.limits[:, 0], bundled.limits[:, 1], (50, 6))
    assert np.abs(expanded.fk(q) - bundled.fk(q)).max() < 1e-9
    packages = ["--package", f"abb_resources={ROS / 'abb_resources'}", "--package", str(ROS / "abb_irb120_support")]
    assert main(["fk", str(XACRO), "0", "0.5", "0", "0", "0", "0", *packages]) == 0
    assert "T_W_n (m) of abb_irb120_3_58" in capsys.readouterr().out


@needs_ros
@pytest.mark.parametrize("rigid_fit", [["--rigid-fit"], ["--no-rigid-fit"]])
def test_a_dh_calibration_goes_into_the_vendor_urdf(tmp_path, rigid_fit):
    """The bundled IRB 120 calibrated (every parameter off nominal, compliances too) into the
    vendor's xacro: only joint origins change (the revolute joints', and joint_6-flange's where the
    calibration tilts the flange off axis 6); the URDF's FK (yourdfpy) is the calibrated rigid
    model's to 1e-9 m at random configurations."""
    robot = fgcal.load_robot("abb_irb120")
    rng = np.random.default_rng(8)
    save_robot(tmp_path / "calibrated_robot.yaml", robot, random_parameters(robot, rng))
    calibrated = fgcal.load_robot(tmp_path / "calibrated_robot.yaml")
    out = tmp_path / "irb120_calibrated.urdf"
    argv = ["export", str(tmp_path / "calibrated_robot.yaml"), "--urdf", str(out), "--template", str(XACRO)]
    assert main([*argv, *rigid_fit]) == 0

    q = rng.uniform(calibrated.limits[:, 0], calibrated.limits[:, 1], (40, 6))
    got = _tool0(_yourdfpy(out), q)
    # The same export in fgcal's own layout, whose flange link is the robot's flange.
    own = tmp_path / "own.urdf"
    assert main(["export", str(tmp_path / "calibrated_robot.yaml"), "--urdf", str(own), *rigid_fit]) == 0
    assert np.abs(got - _tool0(_yourdfpy(own), q, "flange")).max() < 1e-9
    if rigid_fit == ["--no-rigid-fit"]:  # the calibrated rigid model itself
        from fgcal.model.rigid_fit import without_compliances
        from fgcal.model.urdf_export import joint_frames

        rigid = without_compliances(calibrated)
        expected = np.linalg.inv(joint_frames(rigid)["base"]) @ rigid.fk(q)
        assert np.abs(got - expected).max() < 1e-9

    # Only joint origins differ from the vendor's document (as xacro expands it).
    from fgcal.model.xacro_io import expand

    parser = etree.XMLParser(remove_comments=True)
    before = etree.fromstring(expand(XACRO)[0].encode(), parser)
    after = etree.parse(str(out), parser).getroot()
    assert [e.tag for e in before.iter()] == [e.tag for e in after.iter()]
    changed = set()
    for a, b in zip(before.iter(), after.iter(), strict=True):
        if dict(a.attrib) != dict(b.attrib):
            assert a.tag == "origin" and a.getparent().tag == "joint", (a.tag, a.attrib, b.attrib)
            changed.add(a.getparent().get("name"))
    assert {f"joint_{i}" for i in range(1, 7)} <= changed <= {*(f"joint_{i}" for i in range(1, 7)), "joint_6-flange"}
    text = out.read_text()
    assert 'velocity="4.36332"' in text and "irb120_3_58/visual/link_3.stl" in text  # the vendor's, kept


@needs_ros
def test_the_nominal_irb120_into_its_xacro_changes_nothing(tmp_path):
    """The nominal DH robot written into the vendor's URDF: every origin as the vendor's to 1e-12."""
    assert main(["export", "abb_irb120", "--urdf", str(tmp_path / "n.urdf"), "--template", str(XACRO)]) == 0
    from fgcal.model.urdf_io import _parse

    mine = {j.name: j.origin for j in _parse(tmp_path / "n.urdf").joints}
    theirs = {j.name: j.origin for j in _parse(XACRO).joints}
    assert mine.keys() == theirs.keys()
    assert max(np.abs(mine[k] - theirs[k]).max() for k in mine) < 1e-12


@needs_ros
def test_another_robot_is_refused_by_the_vendor_urdf(tmp_path, capsys):
    code = main(["export", "kuka_kr125_2", "--urdf", str(tmp_path / "k.urdf"), "--template", str(XACRO)])
    assert code == 2
    err = capsys.readouterr().err
    assert "is not the URDF" in err and "irb120_3_58.xacro" in err and "\n" not in err.strip()
    assert not (tmp_path / "k.urdf").exists()


def test_no_output_overwrites_what_a_xacro_includes(tmp_path, capsys):
    """xacro may include any file (here one named .urdf): the export never writes over it."""
    package = tmp_path / "arm_pkg"
    package.mkdir()
    macro = package / "macro.urdf"
    macro.write_text(
        '<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:macro name="arm" params="prefix">'
        '<link name="${prefix}base_link"/><link name="${prefix}tool0"/><joint name="${prefix}joint_1" '
        'type="revolute"><parent link="${prefix}base_link"/><child link="${prefix}tool0"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></xacro:macro></robot>'
    )
    (package / "arm.xacro").write_text(
        '<robot name="arm" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        '<xacro:include filename="$(find arm_pkg)/macro.urdf"/><xacro:arm prefix=""/></robot>'
    )
    before = macro.read_text()
    assert main(["export", str(package / "arm.xacro"), "--urdf", str(macro)]) == 2
    err = capsys.readouterr().err
    assert "same file" in err and "macro.urdf" in err
    assert macro.read_text() == before
    assert main(["export", str(package / "arm.xacro"), "--urdf", str(tmp_path / "arm.urdf")]) == 0
    assert fgcal.load_robot(tmp_path / "arm.urdf").n_joints == 1
