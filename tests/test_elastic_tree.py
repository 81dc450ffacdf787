"""Issue 40, items 1-3: fixed (calibratable) frames before any row and at a tip, loads on any link
(tip payloads, fixed bodies), compliances about the parent link's axes and coupled compliances.
A parent-axis deflection is the same as massless dummy joints about the parent's axes turned by
k times the moment computed here by hand; a fixed frame is the transform it says, in every
convention; the humanoid's Jacobians (every parameter, both hands) match central differences."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import fgcal
from fgcal.core.se3 import pose_from_xyz_rpy, so3_exp
from fgcal.model import kinematics
from fgcal.model.robot_io import parse_robot, robot_document

G = np.array([0.0, 0.0, -9.81])
ARM = [  # three DH rows (m, rad): shoulder, upper arm, forearm; masses and centres of mass
    {"theta": 0.0, "d": 0.4, "a": 0.1, "alpha": -np.pi / 2, "limits": [-3, 3], "mass": 10.0, "com": [0.0, 0.05, 0.0]},
    {"theta": 0.2, "d": 0.05, "a": 0.5, "alpha": 0.0, "limits": [-3, 3], "mass": 8.0, "com": [-0.25, 0.0, 0.02]},
    {"theta": 0.0, "d": 0.0, "a": 0.4, "alpha": np.pi / 2, "limits": [-3, 3], "mass": 5.0, "com": [-0.2, 0.01, 0.0]},
]
PAYLOAD = {"mass": 3.0, "com": [0.0, 0.02, 0.08]}


def _robot(joints: list[dict], **more) -> fgcal.Robot:
    doc = {"name": "arm", "source": "test", "joints": joints, "payload": PAYLOAD, **more}
    return parse_robot(yaml.safe_load(yaml.safe_dump(doc)), "<test>")


def _dummy(axis: list[float]) -> dict:
    """A massless revolute joint about ``axis`` of its parent's frame, through its origin."""
    return {"origin": {"xyz": [0, 0, 0], "rpy": [0, 0, 0]}, "axis": axis, "limits": [-3, 3], "mass": 0.0}


def _moment(robot: fgcal.Robot, q: np.ndarray, about: int, carried: list[int]) -> np.ndarray:
    """By hand: the gravity moment (N, 3) about frame ``about``'s origin, in its axes, of the links
    ``carried`` and the payload, on the robot's chain at ``q`` (dummies at zero)."""
    data = kinematics.forward(robot, robot.parameter_vector(), q)
    chain = robot.chain
    pose = lambda k: kinematics.frame_pose(robot, data, k)  # noqa: E731
    T_about = pose(about)
    torque = np.zeros((len(q), 3))
    bodies = [(chain.link_end[b], robot.masses[b], robot.coms[b]) for b in carried]
    bodies.append((chain.flange, robot.payload_mass, robot.payload_com))
    for frame, mass, com in bodies:
        T = pose(frame)
        c = np.einsum("nij,j->ni", T[:, :3, :3], com) + T[:, :3, 3]
        torque += np.cross(c - T_about[:, :3, 3], mass * G)
    return np.einsum("nji,nj->ni", T_about[:, :3, :3], torque)


def test_a_parent_axis_compliance_is_dummy_joints_turned_by_its_moment():
    """Joint 2 bends about its parent's x, y and z (DLR's model) and joint 3 by kc3 times joint 2's
    z moment; the same robot without compliances but with massless dummy joints about the
    parent's axes, turned by k times the moments computed by hand, reaches the same flange to
    1e-12 m."""
    k2, kc3 = np.array([2e-3, 3e-3, 1e-3]), 4e-3  # rad/(N m), large: centimetres of deflection
    elastic = _robot(
        [ARM[0], {**ARM[1], "compliance": {"about": "parent"}},
         {**ARM[2], "compliance": {"about": "parent", "coupled_from": 2}}],
        parameters={"kx2": 2e-3, "ky2": 3e-3, "kz2": 1e-3, "kc3": kc3},
    )  # fmt: skip
    dummies = _robot(
        [ARM[0], _dummy([0, 0, 1]), _dummy([0, 1, 0]), _dummy([1, 0, 0]), ARM[1], _dummy([0, 0, 1]), ARM[2]],
        model="DH,s",
    )
    q = np.random.default_rng(1).uniform(-1.5, 1.5, (20, 3))
    at_zero = np.column_stack([q[:, 0], np.zeros((len(q), 3)), q[:, 1], np.zeros(len(q)), q[:, 2]])
    t2 = _moment(dummies, at_zero, dummies.chain.link_end[0], [4, 6])  # joint 2's: frame 1, links 2, 3, payload
    turned = at_zero.copy()
    turned[:, 1], turned[:, 2], turned[:, 3] = k2[2] * t2[:, 2], k2[1] * t2[:, 1], k2[0] * t2[:, 0]
    turned[:, 5] = kc3 * t2[:, 2]
    assert np.abs(turned[:, 1:4]).max() > 1e-2  # the deflections are not negligible
    expected = dummies.fk(turned)
    assert np.abs(elastic.fk(q)[:, :3, 3] - expected[:, :3, 3]).max() < 1e-12
    assert np.abs(elastic.fk(q)[:, :3, :3] - expected[:, :3, :3]).max() < 1e-12
    # About the joint's own axes (the default), the same compliances deflect the flange otherwise.
    about_joint = _robot([ARM[0], ARM[1], ARM[2]], parameters={"kx2": 2e-3, "ky2": 3e-3, "kz2": 1e-3})
    assert np.abs(about_joint.fk(q)[:, :3, 3] - expected[:, :3, 3]).max() > 1e-3
    # The kernel's moment of joint 2 is the one computed by hand (its bending frame: the parent's).
    moments = kinematics.forward(elastic, elastic.parameter_vector(), q).moments
    assert np.allclose(moments[:, 3:6], t2, rtol=1e-12, atol=1e-9)


def test_a_parent_axis_compliance_on_a_branchs_first_joint():
    """A branch's first joint bending about its parent's axes bends at the frame the branch leaves
    from (not at the end of the branch before it): the same as dummy joints there."""
    side = {"theta": 0.0, "d": 0.2, "a": 0.3, "alpha": 0.5, "parent": 1, "limits": [-3, 3], "mass": 4.0,
            "com": [0.0, 0.1, 0.0]}  # fmt: skip
    elastic = _robot(
        [ARM[0], side, {**ARM[1], "parent": 1, "compliance": {"about": "parent"}}, ARM[2]],
        parameters={"kx2": 0.0, "kx3": 2e-3, "ky3": 3e-3, "kz3": 1e-3}, flange_joint=4,
    )  # fmt: skip
    dummies = _robot(
        [ARM[0], side, {**_dummy([0, 0, 1]), "parent": 1}, _dummy([0, 1, 0]), _dummy([1, 0, 0]), ARM[1], ARM[2]],
        model="DH,s", flange_joint=7,
    )  # fmt: skip
    q = np.random.default_rng(9).uniform(-1.5, 1.5, (10, 4))
    at_zero = np.column_stack([q[:, :2], np.zeros((len(q), 3)), q[:, 2:]])
    t3 = _moment(dummies, at_zero, dummies.chain.link_end[0], [5, 6])
    turned = at_zero.copy()
    turned[:, 2], turned[:, 3], turned[:, 4] = 1e-3 * t3[:, 2], 3e-3 * t3[:, 1], 2e-3 * t3[:, 0]
    assert np.abs(elastic.fk(q)[:, :3, 3] - dummies.fk(turned)[:, :3, 3]).max() < 1e-12
    # Its Jacobian (every parameter and joint, at the flange) against central differences.
    from test_kinematics import _fd_columns

    params = elastic.nominal_parameters()
    wrt = elastic.parameter_names + [f"q{i}" for i in range(1, 5)]
    J = elastic.jacobian(q[:3], wrt, params)
    for col, name in enumerate(wrt):
        numeric, _ = _fd_columns(elastic, q[:3], params, name, "flange", np.zeros(3), 1e-6 if name[0] == "k" else 1e-5)
        error = np.linalg.norm(J[:, :, col] - numeric) / max(np.linalg.norm(numeric), 1e-3)
        assert error < 1e-6, (name, error)


@pytest.mark.parametrize("convention", ["standard", "modified", "origin"])
def test_a_fixed_frame_before_a_row_is_the_transform_it_says(convention):
    """A fixed frame (xyz, rpy) and its six parameters between joint 1's link and joint 2's row, in
    each convention: the flange is joint 1's link, the frame (nominal, then the perturbation:
    translation, then rotation vector) and joint 2's row on its own."""
    second = {"theta": 0.3, "d": 0.05, "a": 0.5, "alpha": 0.4, "limits": [-3, 3]}
    if convention == "modified":
        second["convention"] = "modified"
    if convention == "origin":
        second = {"origin": {"xyz": [0.1, 0.0, 0.2], "rpy": [0.2, 0.0, 0.1]}, "axis": [0, 1, 0], "limits": [-3, 3]}
    xyz, rpy = np.array([0.05, 0.25, -0.1]), np.array([0.3, -0.5, 0.8])
    framed = _robot([ARM[0], {**second, "frame": {"name": "mount", "xyz": xyz.tolist(), "rpy": rpy.tolist()}}])
    first, row = _robot([ARM[0]]), _robot([second])
    names = [f"frame.mount.{kind}" for kind in ("tx", "ty", "tz", "rx", "ry", "rz")]
    assert set(names) <= set(framed.parameter_names)
    perturbation = np.array([0.002, -0.001, 0.003, 0.01, -0.02, 0.015])
    q = np.random.default_rng(2).uniform(-1.5, 1.5, (5, 2))
    T_frame = pose_from_xyz_rpy(xyz, rpy)
    T_pert = np.eye(4)
    T_pert[:3, :3], T_pert[:3, 3] = so3_exp(perturbation[3:]), perturbation[:3]
    expected = first.fk(q[:, :1]) @ T_frame @ T_pert @ row.fk(q[:, 1:])
    got = framed.fk(q, dict(zip(names, perturbation, strict=True)))
    assert np.abs(got - expected).max() < 1e-12


def test_a_calibrated_tip_is_its_pose_then_its_perturbation():
    """A tip with ``calibrate: true`` has frame.{tip}.* (translation, then rotation vector) after its
    pose on its link; the flange's own are tool.*."""
    xyz, rpy = [0.0, 0.05, 0.12], [0.0, -1.2, 0.7]
    robot = _robot(ARM, tips=[{"name": "tcp", "joint": 3, "xyz": xyz, "rpy": rpy, "calibrate": True}])
    names = [f"frame.tcp.{kind}" for kind in ("tx", "ty", "tz", "rx", "ry", "rz")]
    assert robot.parameter_names[-18:-12] == names  # before base and tool
    perturbation = np.array([0.001, 0.002, -0.003, 0.02, -0.01, 0.03])
    T_pert = np.eye(4)
    T_pert[:3, :3], T_pert[:3, 3] = so3_exp(perturbation[3:]), perturbation[:3]
    q = np.random.default_rng(6).uniform(-1.5, 1.5, (4, 3))
    expected = robot.fk(q) @ pose_from_xyz_rpy(np.array(xyz), np.array(rpy)) @ T_pert
    assert np.abs(robot.fk(q, dict(zip(names, perturbation, strict=True)), tip="tcp") - expected).max() < 1e-12


def _humanoid_parameters(robot: fgcal.Robot, rng: np.random.Generator) -> dict[str, float]:
    from conftest import random_parameters

    params = random_parameters(robot, rng)
    params["kc3"] = 2e-5
    params["mass.arms"] = 1.2
    return params


def test_humanoid_jacobians_match_central_differences():
    """Every parameter (fixed frames, parent-axis and coupled compliances, mass scale) and every
    joint of the bundled humanoid, at both hands (tip payloads and the head in the moments):
    analytic columns against central differences."""
    from test_kinematics import _fd_columns

    robot = fgcal.load_robot("humanoid_upper_body")
    rng = np.random.default_rng(5)
    params = _humanoid_parameters(robot, rng)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (2, robot.n_joints))
    wrt = robot.parameter_names + [f"q{i}" for i in range(1, robot.n_joints + 1)]
    moments = kinematics.forward(robot, robot.parameter_vector(params), q).moments
    for tip in ("left_hand", "right_hand"):
        J = robot.jacobian(q, wrt, params, frame=tip)
        worst = {}
        for col, name in enumerate(wrt):
            # A compliance's step deflects by 1e-4 rad at most (the moments reach 100 N m).
            step = 1e-4 / max(1.0, np.abs(moments).max()) if name[0] == "k" else 1e-4
            numeric, _ = _fd_columns(robot, q, params, name, tip, np.zeros(3), step)
            worst[name] = np.linalg.norm(J[:, :, col] - numeric) / max(np.linalg.norm(numeric), 1e-3)
        bad = {k: v for k, v in worst.items() if v > 1e-6}
        assert not bad, f"{tip}: Jacobian columns off by more than 1e-6 relative: {bad}"
        for name in ("kc3", "kx2", "ky6" if tip == "left_hand" else "ky13", "mass.arms"):
            assert np.linalg.norm(J[:, :, wrt.index(name)]) > 1e-4, name  # each moves the hand


def test_tip_payloads_and_fixed_bodies_load_the_compliances():
    """A hand's payload loads the joints that carry it (its arm's, the torso's), not the other
    arm's; the head loads the torso's alone; a fixed body on the base, nothing."""
    robot = fgcal.load_robot("humanoid_upper_body")
    q = np.random.default_rng(3).uniform(robot.limits[:, 0], robot.limits[:, 1], (4, robot.n_joints))

    def moments(**change) -> np.ndarray:
        from dataclasses import replace

        other = replace(robot, **change)
        return kinematics.forward(other, other.parameter_vector(), q).moments.reshape(len(q), -1, 3)

    base = moments()
    no_hand = moments(tip_payloads=(robot.tip_payloads[1],))  # the left hand's payload taken off
    changed = np.abs(base - no_hand).max(axis=(0, 2)) > 1e-6
    assert changed[[1, 2, 5]].all() and not changed[11:].any()  # torso pitches, left shoulder; not the right arm
    no_head = moments(fixed_bodies=())
    changed = np.abs(base - no_head).max(axis=(0, 2)) > 1e-6
    assert changed[[0, 1, 2]].all() and not changed[4:].any()
    on_base = moments(fixed_bodies=(*robot.fixed_bodies, ("plinth", -1, 50.0, np.array([0.3, 0.0, 0.0]))))
    assert np.allclose(on_base, base, atol=1e-12)


def test_the_humanoid_robot_file_round_trips():
    """Written back (fgcal's robot document: a calibrated robot file) and read again: the same
    parameters, tips, loads and the same hands, with every new parameter set."""
    robot = fgcal.load_robot("humanoid_upper_body")
    params = _humanoid_parameters(robot, np.random.default_rng(7))
    again = parse_robot(yaml.safe_load(yaml.safe_dump(robot_document(robot, params))), "<round trip>")
    assert again.parameter_names == robot.parameter_names
    assert again.parent_axis == robot.parent_axis and again.compliance_coupling == robot.compliance_coupling
    assert [t for t, _, _ in again.tip_payloads] == ["left_hand", "right_hand"] and len(again.fixed_bodies) == 1
    q = np.random.default_rng(8).uniform(robot.limits[:, 0], robot.limits[:, 1], (5, robot.n_joints))
    for tip in ("left_hand", "right_hand"):
        assert np.abs(again.fk(q, tip=tip) - robot.fk(q, params, tip=tip)).max() < 1e-12


def test_the_humanoid_exports_its_fixed_frames_and_loads(tmp_path, capsys):
    """As a URDF (fgcal's layout of a tree): both hands where fgcal's rigid model puts them, with
    calibrated mounts (the fixed frames are in the joints' origins); the sidecar says which joints
    bend about their parent's axes, the coupled compliance and the loads URDF cannot hold."""
    import yourdfpy

    from fgcal.commands.cli import main
    from fgcal.model.robot_io import save_robot

    robot = fgcal.load_robot("humanoid_upper_body")
    params = {"frame.left_mount.tz": 0.003, "frame.right_mount.rx": 0.01, "kc3": 2e-5, "kx2": 1e-5}
    save_robot(tmp_path / "calibrated.yaml", robot, params)
    assert main(["export", str(tmp_path / "calibrated.yaml"), "--urdf", str(tmp_path / "h.urdf"),
                 "--no-rigid-fit"]) == 0  # fmt: skip
    capsys.readouterr()
    sidecar = yaml.safe_load((tmp_path / "h.compliance.yaml").read_text())
    assert [j.get("about") for j in sidecar["joints"]].count("parent") == 4
    assert sidecar["joints"][2]["coupled_compliance"] == {"from": "joint_2", "kc_rad_per_Nm": 2e-5}
    assert [load.get("tip", load.get("body")) for load in sidecar["loads"]] == ["left_hand", "right_hand", "head"]
    rigid = robot.with_model("DH,s")
    urdf = yourdfpy.URDF.load(str(tmp_path / "h.urdf"), load_meshes=False, build_collision_scene_graph=False)
    for q in np.random.default_rng(4).uniform(robot.limits[:, 0], robot.limits[:, 1], (3, robot.n_joints)):
        values = rigid.geometry_values(q)[0]
        urdf.update_cfg({f"joint_{i + 1}": v for i, v in enumerate(values)})
        for tip in ("left_hand", "right_hand"):
            expected = rigid.fk(q, params, tip=tip)
            np.testing.assert_allclose(urdf.get_transform(tip, "world"), expected, atol=1e-9)
