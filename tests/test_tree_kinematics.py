"""Issue 28 (in part): the elementary transform sequence as a tree. Branches start from any
earlier frame (ET.parent); frames, gravity moments (a trunk joint carries every branch beyond
it) and analytic Jacobians (of any frame: only the elements on its path move it) hold for a
tree as for a serial chain: central differences and direct sums."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yourdfpy
from yaml import safe_load as yaml_load

import fgcal
from fgcal.core.se3 import so3_log
from fgcal.model import kinematics
from fgcal.model.ets import ET, Chain, ancestry, evaluate


@dataclass
class _Tree:
    """A torso joint, arm A (two joints) and arm B (two joints) from the torso's end; arm A
    ends at the flange (with the payload), arm B at its own tip."""

    chain: Chain
    tip_b: int
    parameter_names: list[str]
    masses: np.ndarray
    coms: np.ndarray
    name: str = "tree"
    model: str = "DH,s,e"
    payload_mass: float = 3.0
    payload_com: np.ndarray = None
    gravity: np.ndarray = None
    compliant: bool = True
    history: bool = False
    n_joints: int = 5
    n_links: int = 5
    mass_groups: tuple = ()


def _tree() -> _Tree:
    elements, names, bend, link_end = [], [], [], []

    def param(name: str) -> int:
        names.append(name)
        return len(names) - 1

    def joint(i: int, axis: str, link: list[ET], parent: int | None = None) -> None:
        elements.append(ET(axis, param=param(f"theta{i}"), joint=i - 1, parent=parent))
        bend.append(len(elements))
        elements.extend(
            [
                ET("Rz", param=param(f"kz{i}"), moment=3 * (i - 1) + 2),
                ET("Ry", param=param(f"ky{i}"), moment=3 * (i - 1) + 1),
                ET("Rx", param=param(f"kx{i}"), moment=3 * (i - 1)),
            ]
        )
        elements.extend(link)
        link_end.append(len(elements))

    elements.append(ET("Tz", 0.3))
    base_end = len(elements)
    joint(1, "Rz", [ET("Tz", param=param("d1")), ET("Tx", 0.1)])
    torso_end = len(elements)
    joint(2, "Ry", [ET("Tx", param=param("a2")), ET("Rx", 0.4)], parent=torso_end)  # arm A
    joint(3, "Ry", [ET("Tx", param=param("a3"))])
    flange = len(elements)
    joint(4, "Ry", [ET("Ty", param=param("a4")), ET("Rz", -0.7)], parent=torso_end)  # arm B, from the torso
    joint(5, "Rx", [ET("Ty", param=param("a5"))])
    tip_b = len(elements)
    chain = Chain(tuple(elements), base_end, tuple(bend), tuple(link_end), flange)
    rng = np.random.default_rng(3)
    return _Tree(chain, tip_b, names, rng.uniform(2, 20, 5), rng.uniform(-0.1, 0.1, (5, 3)),
                 payload_com=np.array([0.01, 0.0, 0.05]), gravity=np.array([0.0, 0.0, -9.81]))  # fmt: skip


def _params(tree: _Tree) -> np.ndarray:
    rng = np.random.default_rng(5)
    values = []
    for name in tree.parameter_names:
        if name[0] == "k":
            values.append(rng.uniform(1e-4, 5e-4))
        elif name.startswith("theta"):
            values.append(rng.normal(0, 0.1))
        else:
            values.append(rng.uniform(0.2, 0.5))
    return np.array(values)


def test_branches_start_where_they_leave_the_trunk():
    tree = _tree()
    paths = ancestry(tree.chain.elements)
    torso_end = tree.chain.link_end[0]
    # Arm B's tip is moved by the torso and arm B, not by arm A; arm A's flange the other way round.
    arm_a = range(torso_end, tree.chain.flange)
    arm_b = range(tree.chain.flange, tree.tip_b)
    assert not paths[tree.tip_b, list(arm_a)].any() and paths[tree.tip_b, list(arm_b)].all()
    assert not paths[tree.chain.flange, list(arm_b)].any() and paths[tree.chain.flange, :torso_end].all()
    # Each tip's pose is the product of the transforms along its own path.
    q = np.random.default_rng(1).uniform(-1, 1, (4, 5))
    params = _params(tree)
    frames = evaluate(tree.chain.elements, params, q, np.zeros((4, 15)))
    for tip in (tree.chain.flange, tree.tip_b):
        path = [k for k in range(len(tree.chain.elements)) if paths[tip, k]]
        alone = evaluate(tuple(ET(**{**e.__dict__, "parent": None}) for e in (tree.chain.elements[k] for k in path)),
                         params, q, np.zeros((4, 15)))  # fmt: skip
        np.testing.assert_allclose(frames[tip], alone[-1], atol=1e-14)


def test_a_trunk_joint_carries_every_branch():
    tree = _tree()
    params = _params(tree)
    q = np.random.default_rng(2).uniform(-1, 1, (3, 5))
    data = kinematics.forward(tree, params, q)
    masses = np.append(tree.masses, tree.payload_mass)
    coms = np.vstack([tree.coms, tree.payload_com])
    body_frames = [*tree.chain.link_end, tree.chain.flange]
    carried = {1: [0, 1, 2, 3, 4, 5], 2: [1, 2, 5], 3: [2, 5], 4: [3, 4], 5: [4]}  # body 5 is the payload
    for i, bodies in carried.items():
        bend = data.frames_rigid[tree.chain.bend[i - 1]]
        total = np.zeros((3, 3))
        for b in bodies:
            frame = data.frames_rigid[body_frames[b]]
            c = frame[:, :3, :3] @ coms[b] + frame[:, :3, 3]
            total += np.cross(c - bend[:, :3, 3], masses[b] * tree.gravity)
        expected = np.einsum("nji,nj->ni", bend[:, :3, :3], total)
        np.testing.assert_allclose(data.moments[:, 3 * (i - 1) : 3 * i], expected, rtol=1e-12, atol=1e-9)


def _pose_of(tree, params, q, frame):
    data = kinematics.forward(tree, params, q)
    return kinematics.frame_pose(tree, data, frame)


def test_jacobians_of_both_tips_match_central_differences():
    tree = _tree()
    params = _params(tree)
    q = np.random.default_rng(4).uniform(-1, 1, (3, 5))
    wrt = tree.parameter_names + [f"q{i}" for i in range(1, 6)]
    data = kinematics.forward(tree, params, q)
    for frame in ("flange", tree.tip_b):
        J = kinematics.jacobian(tree, data, wrt, frame=frame)  # body twists (N, 6, T)
        T0 = _pose_of(tree, params, q, frame)
        for col, name in enumerate(wrt):
            step = 1e-7 if name[0] == "k" else 1e-6
            shifted = []
            for sign in (1, -1):
                p, qq = params.copy(), q.copy()
                if name.startswith("q"):
                    qq[:, int(name[1:]) - 1] += sign * step
                else:
                    p[wrt.index(name)] += sign * step
                shifted.append(_pose_of(tree, p, qq, frame))
            R0t = np.swapaxes(T0[:, :3, :3], 1, 2)
            d_rot = (so3_log(R0t @ shifted[0][:, :3, :3]) - so3_log(R0t @ shifted[1][:, :3, :3])) / (2 * step)
            d_pos = np.einsum("nij,nj->ni", R0t, shifted[0][:, :3, 3] - shifted[1][:, :3, 3]) / (2 * step)
            numeric = np.concatenate([d_rot, d_pos], axis=1)
            scale = max(np.linalg.norm(numeric), 1e-9)
            assert np.linalg.norm(J[:, :, col] - numeric) / scale < 1e-6, (frame, name)
        # Arm A's joints do not move arm B's tip, except through the torso's gravity moment.
        if frame == tree.tip_b:
            assert np.linalg.norm(J[:, :, wrt.index("a2")]) > 0  # its weight bends the torso
            flat = kinematics.forward(tree, np.where([n[0] == "k" for n in tree.parameter_names], 0.0, params), q)
            rigid = kinematics.jacobian(tree, flat, ["a2", "q3"], frame=frame)
            assert np.abs(rigid).max() == 0.0


PUMA_CRAIG = """\
name: PUMA 560 (Craig's modified DH)
source: Craig, Introduction to Robotics, 3rd ed., table 3.4 (a2, d3, a3, d4 in m)
dh_convention: modified
units: {length: m, angle: deg}
joints:
  - {alpha: 0, a: 0, theta: 0, d: 0, limits: [-160, 160], mass: 10, com: [0, 0, 0.1]}
  - {alpha: -90, a: 0, theta: 0, d: 0, limits: [-225, 45], mass: 17, com: [0.2, 0, 0]}
  - {alpha: 0, a: 0.4318, theta: 0, d: 0.15005, limits: [-45, 225], mass: 5, com: [0.02, 0, 0.1]}
  - {alpha: -90, a: 0.0203, theta: 0, d: 0.4318, limits: [-110, 170], mass: 1, com: [0, 0, 0]}
  - {alpha: 90, a: 0, theta: 0, d: 0, limits: [-100, 100], mass: 0.5, com: [0, 0, 0]}
  - {alpha: -90, a: 0, theta: 0, d: 0, convention: modified, limits: [-266, 266], mass: 0.2, com: [0, 0, 0.03]}
tool: {xyz: [0, 0, 0.1], rpy: [0, 0, 0]}
"""


def _craig_link(alpha: float, a: float, theta: float, d: float) -> np.ndarray:
    """Craig's eq. (3.6): T = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i) Tz(d_i), written out."""
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array([
        [ct, -st, 0.0, a],
        [st * ca, ct * ca, -sa, -sa * d],
        [st * sa, ct * sa, ca, ca * d],
        [0.0, 0.0, 0.0, 1.0],
    ])  # fmt: skip


def test_modified_dh_equals_craigs_convention(tmp_path):
    import fgcal
    from fgcal.model.robot_io import load_robot, save_robot

    path = tmp_path / "puma_craig.yaml"
    path.write_text(PUMA_CRAIG)
    robot = load_robot(path)
    table = np.array([[0, 0, 0, 0], [-90, 0, 0, 0], [0, 0.4318, 0, 0.15005], [-90, 0.0203, 0, 0.4318],
                      [90, 0, 0, 0], [-90, 0, 0, 0]], dtype=float)  # fmt: skip
    q = np.random.default_rng(8).uniform(-np.pi, np.pi, (20, 6))
    for k in range(len(q)):
        T = np.eye(4)
        for (alpha, a, theta, d), qi in zip(table, q[k], strict=True):
            T = T @ _craig_link(np.radians(alpha), a, np.radians(theta) + qi, d)
        np.testing.assert_allclose(robot.fk(q[k]), T, atol=1e-12)
        np.testing.assert_allclose(robot.fk_tool(q[k])[:3, 3], (T @ [0, 0, 0.1, 1])[:3], atol=1e-12)
    # Written back, it reads as the same robot.
    save_robot(tmp_path / "again.yaml", robot)
    np.testing.assert_allclose(fgcal.load_robot(tmp_path / "again.yaml").fk(q), robot.fk(q), atol=1e-15)


def test_modified_dh_jacobians_match_central_differences(tmp_path):
    from conftest import random_parameters

    import fgcal

    (tmp_path / "puma_craig.yaml").write_text(PUMA_CRAIG)
    robot = fgcal.load_robot(tmp_path / "puma_craig.yaml").with_tool(np.eye(4), payload_mass=5.0)
    rng = np.random.default_rng(9)
    params = random_parameters(robot, rng)
    q = rng.uniform(-2, 2, (3, 6))
    wrt = [n for n in robot.parameter_names if not n.startswith(("lm", "lv"))] + [f"q{i}" for i in range(1, 7)]
    J = robot.jacobian(q, wrt, params, point=np.array([0.05, 0.0, 0.1]))
    for col, name in enumerate(wrt):
        step = 1e-7 if name[0] == "k" else 1e-6
        moved = []
        for sign in (1, -1):
            p, qq = dict(params), q.copy()
            if name.startswith("q"):
                qq[:, int(name[1:]) - 1] += sign * step
            else:
                p[name] += sign * step
            T = robot.fk(qq, p)
            moved.append(T[:, :3, :3] @ [0.05, 0.0, 0.1] + T[:, :3, 3])
        numeric = (moved[0] - moved[1]) / (2 * step)
        assert np.linalg.norm(J[:, :, col] - numeric) <= 1e-6 * max(np.linalg.norm(numeric), 1e-3), name


TREE_URDF = """<?xml version="1.0"?>
<robot name="torso_two_arms">
  <link name="base"><inertial><mass value="20"/><origin xyz="0 0 0.1"/></inertial></link>
  <link name="torso"><inertial><mass value="12"/><origin xyz="0 0 0.2"/></inertial></link>
  <link name="chest"/>
  <link name="a1"><inertial><mass value="4"/><origin xyz="0.1 0 0"/></inertial></link>
  <link name="a2"><inertial><mass value="3"/><origin xyz="0.1 0 0"/></inertial></link>
  <link name="hand_a"/>
  <link name="b1"><inertial><mass value="4"/><origin xyz="0 0.1 0"/></inertial></link>
  <link name="hand_b"><inertial><mass value="1"/></inertial></link>
  <link name="camera"/>
  <joint name="waist" type="revolute"><parent link="base"/><child link="torso"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="chest_fixed" type="fixed"><parent link="torso"/><child link="chest"/>
    <origin xyz="0 0 0.5" rpy="0 0.1 0"/></joint>
  <joint name="a_shoulder" type="revolute"><parent link="chest"/><child link="a1"/>
    <origin xyz="0 0.2 0" rpy="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <joint name="a_elbow" type="revolute"><parent link="a1"/><child link="a2"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="a_hand" type="fixed"><parent link="a2"/><child link="hand_a"/><origin xyz="0.25 0 0"/></joint>
  <joint name="b_shoulder" type="revolute"><parent link="chest"/><child link="b1"/>
    <origin xyz="0 -0.2 0" rpy="-0.3 0 0"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
  <joint name="b_slide" type="prismatic"><parent link="b1"/><child link="hand_b"/>
    <origin xyz="0 -0.3 0"/><axis xyz="0 -1 0"/><limit lower="0" upper="0.2" effort="1" velocity="1"/></joint>
  <joint name="head" type="fixed"><parent link="torso"/><child link="camera"/><origin xyz="0.1 0 0.7"/></joint>
</robot>
"""


def test_a_urdf_with_several_leaves_is_a_tree_with_named_tips(tmp_path):
    """Issue 28: no tool0 and three leaves: every moving joint, every leaf a named tip; each
    tip's FK equals yourdfpy's to 1e-9; written and read back as YAML, the same tree."""
    import yourdfpy

    import fgcal
    from fgcal.model.robot_io import save_robot

    path = tmp_path / "tree.urdf"
    path.write_text(TREE_URDF)
    robot = fgcal.load_robot(path)
    assert robot.n_joints == 5 and robot.parents is not None
    assert robot.tip_names == ["hand_a", "hand_b", "camera"]  # the deepest leaf is the flange
    reference = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
    order = ["waist", "a_shoulder", "a_elbow", "b_shoulder", "b_slide"]
    rng = np.random.default_rng(6)
    q = np.column_stack([rng.uniform(-2, 2, (12, 4)), rng.uniform(0, 0.2, 12)])
    again_path = tmp_path / "tree.yaml"
    save_robot(again_path, robot)
    again = fgcal.load_robot(again_path)
    for qi in q:
        reference.update_cfg(dict(zip(order, qi, strict=True)))
        for tip in robot.tip_names:
            expected = reference.get_transform(frame_to=tip, frame_from="base")
            np.testing.assert_allclose(robot.fk(qi, tip=tip), expected, atol=1e-9)
            np.testing.assert_allclose(again.fk(qi, tip=tip), expected, atol=1e-12)
    # The waist carries both arms: its body is the torso (chest and camera are fixed to it).
    np.testing.assert_allclose(robot.masses, [12, 4, 3, 4, 1])
    assert robot.parents == (-1, 0, 1, 0, 3)


def test_two_leaves_one_on_the_root(tmp_path, capsys):
    """A leaf fixed to the root is a tip that no joint moves; fgcal fk prints every tip."""
    from fgcal.commands.cli import main

    path = tmp_path / "two.urdf"
    path.write_text(
        "<robot name='x'><link name='a'/><link name='b'/><link name='c'/>"
        "<joint name='j' type='continuous'><parent link='a'/><child link='b'/><origin xyz='0 0 1'/></joint>"
        "<joint name='k' type='fixed'><parent link='a'/><child link='c'/><origin xyz='0.5 0 0'/></joint></robot>"
    )
    assert main(["fk", str(path), "0.3"]) == 0
    out = capsys.readouterr().out
    assert "T_W_b" in out and "T_W_c" in out
    import fgcal

    robot = fgcal.load_robot(path)
    np.testing.assert_allclose(robot.fk(np.array([0.3]), tip="c")[:3, 3], [0.5, 0, 0])
    np.testing.assert_allclose(robot.fk(np.array([1.0]), tip="c"), robot.fk(np.array([0.0]), tip="c"))


def test_a_tree_calibrates_on_its_flange_and_exports_in_fgcals_layout(tmp_path, capsys):
    """A tree robot in a tracker cell: the flange's chain calibrates (the other branches'
    parameters are not identifiable from it); fgcal export writes the tree in fgcal's own
    layout (each tip a link by its name), and refuses to write it into a template."""
    import yaml

    from fgcal.commands.cli import main

    (tmp_path / "tree.urdf").write_text(TREE_URDF)
    cell = yaml.safe_load((Path(__file__).parent.parent / "datasets" / "cells" / "irb120_tracker.yaml").read_text())
    cell["robot"] = "tree.urdf"
    cell["perturbation"]["compliant_joints"] = [1]
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "data"), "--n", "60"]) == 0
    assert main(["calibrate", str(tmp_path / "data" / "calibration.yaml"), "--out", str(tmp_path / "out"),
                 "--no-plots", "--json"]) == 0  # fmt: skip
    capsys.readouterr()
    calibrated = tmp_path / "out" / "calibrated_robot.yaml"
    template = ["--template", str(tmp_path / "tree.urdf")]
    assert main(["export", str(calibrated), "--urdf", str(tmp_path / "x.urdf"), *template]) == 2
    error = capsys.readouterr()
    assert "is a tree" in error.err and "URDF alone" not in error.out + error.err
    assert main(["export", str(calibrated), "--urdf", str(tmp_path / "x.urdf")]) == 0
    robot = fgcal.load_robot(calibrated).with_model("DH,s")  # what a URDF holds: no compliances
    urdf = yourdfpy.URDF.load(str(tmp_path / "x.urdf"), load_meshes=False, build_collision_scene_graph=False)
    q = np.random.default_rng(2).uniform(robot.limits[:, 0], robot.limits[:, 1], (4, robot.n_joints))
    for row in q:
        urdf.update_cfg(dict(zip(urdf.actuated_joint_names, row, strict=True)))
        for tip in robot.tip_names:
            link = tip if tip not in ("tool0", "world", "base_link") else f"{tip}_tip"
            np.testing.assert_allclose(urdf.get_transform(link, "world"), robot.fk(row, tip=tip), atol=1e-9)


def test_the_dual_arm_tree_exports_with_its_coupled_joint(tmp_path, capsys):
    """The bundled dual-arm torso as a URDF: every link, the coupled joint said in a comment
    (URDF's mimic follows one joint), both hands; FK equals fgcal's rigid model to 1e-9 with the
    coupled joint set to its value."""
    from fgcal.commands.cli import main

    assert main(["export", "dual_arm_torso", "--urdf", str(tmp_path / "d.urdf")]) == 0
    capsys.readouterr()
    text = (tmp_path / "d.urdf").read_text()
    assert "joint_4 follows several joints: set its value to -1 joint_2 -1 joint_3" in text
    sidecar = yaml_load((tmp_path / "d.compliance.yaml").read_text())
    assert sidecar["joints"][3]["follows"] == {"joint_2": -1.0, "joint_3": -1.0}
    assert sidecar["mass_scales"] == {"arms": 1.0}
    robot = fgcal.load_robot("dual_arm_torso").with_model("DH,s")
    urdf = yourdfpy.URDF.load(str(tmp_path / "d.urdf"), load_meshes=False, build_collision_scene_graph=False)
    for q in np.random.default_rng(4).uniform(robot.limits[:, 0], robot.limits[:, 1], (4, robot.n_joints)):
        values = robot.geometry_values(q)[0]
        np.testing.assert_allclose(values[3], -q[1] - q[2])
        urdf.update_cfg({f"joint_{i + 1}": v for i, v in enumerate(values)})
        np.testing.assert_allclose(urdf.get_transform("left_hand", "world"), robot.fk(q), atol=1e-9)
        np.testing.assert_allclose(urdf.get_transform("right_hand", "world"), robot.fk(q, tip="right_hand"), atol=1e-9)


def test_coupled_joint_follows_its_leaders():
    """The bundled dual-arm torso: q4 = -q2 - q3 keeps the torso's top level, whatever q2, q3."""
    import fgcal

    robot = fgcal.load_robot("dual_arm_torso")
    assert (robot.n_joints, robot.n_links) == (17, 18)
    assert robot.tip_names == ["left_hand", "right_hand"]
    rng = np.random.default_rng(3)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (6, robot.n_joints))
    data = kinematics.forward(robot, robot.parameter_vector(), q)
    top = data.frames[robot.chain.link_end[3]]
    np.testing.assert_allclose(top[:, 2, 2], 1.0, atol=1e-12)  # z stays vertical
    # The top's orientation does not change with q2 or q3 (their motions cancel through joint
    # 4), and the coupled joint's own offset turns it.
    J = kinematics.jacobian(robot, data, ["theta4", "q2", "q3"], frame=robot.chain.link_end[3])
    np.testing.assert_allclose(J[:, :3, 1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(J[:, :3, 0], axis=1), 1.0, atol=1e-12)


def test_dual_arm_jacobians_with_coupling_and_mass_scale_match_central_differences():
    """Every parameter of the tree (the coupled joint's, the mass scale, the motion terms) and
    every joint, on both hands: analytic columns against central differences."""
    from conftest import random_parameters
    from test_kinematics import _fd_columns

    import fgcal
    from fgcal.model.motion import MotionHistory, features

    robot = fgcal.load_robot("dual_arm_torso").with_model("DH,s,e,h")
    rng = np.random.default_rng(5)
    params = random_parameters(robot, rng)
    params["mass.arms"] = 1.3
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (3, robot.n_joints))
    motion = features(q, MotionHistory(q - rng.uniform(-0.5, 0.5, q.shape), rng.uniform(0.2, 1.0, 3)))
    wrt = robot.parameter_names + [f"q{i}" for i in range(1, robot.n_joints + 1)]
    moments = kinematics.forward(robot, robot.parameter_vector(params), q, motion).moments
    for tip in robot.tip_names:
        J = robot.jacobian(q, wrt, params, frame=tip, motion=motion)
        worst = {}
        for col, name in enumerate(wrt):
            # 1e-4: one arm's parameters move the other hand by 1e-5 of theirs (through the
            # torso's compliance), where a 1e-6 step's rounding is already 1e-5 of the column;
            # the truncation error of 1e-4 is 1e-8 of a column.
            step = 1e-4
            if name[0] == "k":
                component = 3 * (int(name[2:]) - 1) + "xyz".index(name[1])
                step = 1e-4 / max(1.0, np.abs(moments[:, component]).max())
            numeric, _ = _fd_columns(robot, q, params, name, tip, np.zeros(3), step, motion)
            # Relative to the column, or to 1e-3 for the tiny ones (a hand moved by the other
            # arm through the torso's compliance), whose differences are at rounding's floor.
            worst[name] = np.linalg.norm(J[:, :, col] - numeric) / max(np.linalg.norm(numeric), 1e-3)
        bad = {k: v for k, v in worst.items() if v > 1e-6}
        assert not bad, f"{tip}: Jacobian columns off by more than 1e-6 relative: {bad}"
        # The mass scale moves both hands (the torso's compliances carry the arms).
        assert np.linalg.norm(J[:, :, wrt.index("mass.arms")]) > 1e-4


def test_a_joint_coupled_to_one_other_exports_as_a_mimic(tmp_path, capsys):
    """q4 = -q2 + 10 deg: URDF's mimic (multiplier, offset), which yourdfpy follows; FK of both
    hands equals fgcal's rigid model to 1e-9."""
    from fgcal.commands.cli import main

    doc = yaml_load((Path(__file__).parent.parent / "datasets" / "robots" / "dual_arm_torso.yaml").read_text())
    doc["joints"][3]["coupling"] = {"joints": [2], "coefficients": [-1], "offset": 10}
    (tmp_path / "robot.yaml").write_text(__import__("yaml").safe_dump(doc))
    assert main(["export", str(tmp_path / "robot.yaml"), "--urdf", str(tmp_path / "m.urdf")]) == 0
    capsys.readouterr()
    assert '<mimic joint="joint_2" multiplier="-1" offset="0.174532925199433"/>' in (tmp_path / "m.urdf").read_text()
    robot = fgcal.load_robot(tmp_path / "robot.yaml").with_model("DH,s")
    urdf = yourdfpy.URDF.load(str(tmp_path / "m.urdf"), load_meshes=False, build_collision_scene_graph=False)
    assert "joint_4" not in urdf.actuated_joint_names and len(urdf.actuated_joint_names) == robot.n_joints
    for q in np.random.default_rng(6).uniform(robot.limits[:, 0], robot.limits[:, 1], (4, robot.n_joints)):
        urdf.update_cfg(q)
        np.testing.assert_allclose(urdf.get_transform("left_hand", "world"), robot.fk(q), atol=1e-9)
        np.testing.assert_allclose(urdf.get_transform("right_hand", "world"), robot.fk(q, tip="right_hand"), atol=1e-9)
