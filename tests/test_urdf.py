"""URDF in and out, checked against yourdfpy (an independent URDF implementation)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
import yourdfpy
from conftest import REPO, random_parameters, random_urdf

import fgcal
from fgcal.commands.cli import main
from fgcal.core.se3 import pose_from_xyz_rpy
from fgcal.model import kinematics
from fgcal.model.robot_io import bundled_robots, save_robot
from fgcal.model.urdf_export import export_urdf


def _yourdfpy(path):
    return yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)


def _pose_error(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.abs(A - B).max())


@pytest.mark.parametrize("seed", range(6))
def test_urdf_fk_matches_yourdfpy(tmp_path, seed):
    rng = np.random.default_rng(seed)
    n = 6 + seed % 2
    path = random_urdf(tmp_path / "arm.urdf", rng, n, prismatic=3 if seed == 5 else None)
    robot = fgcal.load_robot(path)
    assert robot.n_joints == n and robot.prismatic.sum() == (seed == 5)
    reference = _yourdfpy(path)
    for q in rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (10, n)):
        reference.update_cfg(q)
        assert _pose_error(robot.fk(q), reference.get_transform("tool0", "root")) < 1e-9
        # Another tip: the chain ends at the link of the last moving joint.
        assert (
            _pose_error(fgcal.load_robot(path, tip=f"link_{n}").fk(q), reference.get_transform(f"link_{n}", "root"))
            < 1e-9
        )


def test_urdf_lumped_masses_match_yourdfpy_links(tmp_path):
    """The weight of everything joint 1 carries: fgcal's lumped bodies against every link's
    inertial placed by yourdfpy, at random configurations."""
    rng = np.random.default_rng(3)
    path = random_urdf(tmp_path / "arm.urdf", rng, 7)
    robot = fgcal.load_robot(path)
    reference = _yourdfpy(path)
    links = reference.robot.links
    carried = set(reference.robot.links[i].name for i in range(len(links))) - {"root", "adapter_1"}
    for q in rng.uniform(-1, 1, (4, 7)):
        reference.update_cfg(q)
        mass, moment = 0.0, np.zeros(3)
        for link in links:
            if link.name in carried and link.inertial is not None:
                T = reference.get_transform(link.name, "root")
                mass += link.inertial.mass
                moment += link.inertial.mass * (T[:3, :3] @ link.inertial.origin[:3, 3] + T[:3, 3])
        data = kinematics.forward(robot, robot.parameter_vector(), q[None])
        body_frames = data.frames_rigid[list(robot.chain.link_end)][:, 0]
        ours = sum(
            m * (F[:3, :3] @ c + F[:3, 3]) for m, c, F in zip(robot.masses, robot.coms, body_frames, strict=True)
        )
        assert robot.masses.sum() == pytest.approx(mass, rel=1e-12)
        np.testing.assert_allclose(ours, moment, atol=1e-9)


def test_exported_urdf_matches_tool_pose_for_every_bundled_robot(tmp_path):
    rng = np.random.default_rng(0)
    for name in bundled_robots():
        robot = fgcal.load_robot(name)
        urdf, _ = export_urdf(robot, tmp_path / f"{name}.urdf")
        reference = _yourdfpy(urdf)
        for q in rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (10, robot.n_joints)):
            reference.update_cfg(robot.geometry_values(q)[0])  # a coupled joint is a joint of the URDF
            if robot.urdf is None:  # fgcal's own layout: world is W, tool0 the tool
                assert _pose_error(reference.get_transform("tool0", "world"), robot.fk_tool(q)) < 1e-9, name
            else:  # the robot's own URDF: its root is the base frame, its tip the flange
                tip = robot.urdf[1]
                assert _pose_error(reference.get_transform(tip, reference.base_link), robot.fk(q)) < 1e-9, name


@pytest.mark.parametrize("source", ["kuka_kr125_2", "random_urdf"])
def test_exported_calibrated_robot_round_trip(tmp_path, source):
    """A calibrated robot (every parameter off nominal, base, tool and payload set), saved as
    fgcal YAML, exported: yourdfpy's world -> tool0 is fgcal's tool pose with the compliances
    at zero, and the URDF loads back into fgcal with the same rigid kinematics."""
    rng = np.random.default_rng(4)
    if source == "random_urdf":
        nominal = fgcal.load_robot(random_urdf(tmp_path / "arm.urdf", rng, 7))
    else:
        nominal = fgcal.load_robot(source)
    nominal = nominal.with_tool(pose_from_xyz_rpy([0.01, 0.02, 0.15], [0.1, -0.2, 0.3]), 12.0, [0, 0, 0.1])
    params = random_parameters(nominal, rng)
    save_robot(tmp_path / "calibrated_robot.yaml", nominal, params)
    calibrated = fgcal.load_robot(tmp_path / "calibrated_robot.yaml")
    assert main(["export", str(tmp_path / "calibrated_robot.yaml"), "--urdf", str(tmp_path / "out.urdf")]) == 0
    reference = _yourdfpy(tmp_path / "out.urdf")
    rigid = {k: 0.0 for k in calibrated.parameter_names if k[:2] in ("kx", "ky", "kz")}
    reloaded = fgcal.load_robot(tmp_path / "out.urdf")
    assert "out.compliance.yaml" in (tmp_path / "out.urdf").read_text()
    sidecar = yaml.safe_load((tmp_path / "out.compliance.yaml").read_text())
    placement = pose_from_xyz_rpy(sidecar["base_in_world"]["xyz_m"], sidecar["base_in_world"]["rpy_rad"])
    tool = pose_from_xyz_rpy(sidecar["tool_in_flange"]["xyz_m"], sidecar["tool_in_flange"]["rpy_rad"])
    for q in rng.uniform(calibrated.limits[:, 0], calibrated.limits[:, 1], (10, calibrated.n_joints)):
        reference.update_cfg(q)
        expected = calibrated.fk_tool(q, rigid)
        if source == "random_urdf":  # written into its own URDF: root = base frame 0, tip = flange
            flange = reference.get_transform("tool0", reference.base_link)
            assert _pose_error(placement @ flange @ tool, expected) < 1e-9
            assert _pose_error(placement @ reloaded.fk(q) @ tool, expected) < 1e-9
        else:
            assert _pose_error(reference.get_transform("tool0", "world"), expected) < 1e-9
            assert _pose_error(reloaded.fk(q), expected) < 1e-9
    # The sidecar keeps the compliances (and the payload the URDF's flange inertial carries).
    values = calibrated.nominal_parameters()
    assert sidecar["joints"][1]["compliance_rad_per_Nm"] == [values[f"{k}2"] for k in ("kx", "ky", "kz")]
    assert sidecar["payload"]["mass_kg"] == 12.0
    if source != "random_urdf":
        assert reloaded.masses.sum() == pytest.approx(calibrated.masses.sum() + 12.0)


def test_urdf_robot_saved_as_yaml_reloads_exactly(tmp_path):
    rng = np.random.default_rng(9)
    robot = fgcal.load_robot(random_urdf(tmp_path / "arm.urdf", rng, 6, prismatic=2))
    params = random_parameters(robot, rng)
    save_robot(tmp_path / "robot.yaml", robot, params)
    again = fgcal.load_robot(tmp_path / "robot.yaml")
    assert again.parameter_names == robot.parameter_names
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (5, 6))
    np.testing.assert_allclose(again.fk_tool(q), robot.fk_tool(q, params), atol=1e-12)


BAD_URDFS = {
    "malformed": ("<robot name='x'><link name='a'></robot>", "malformed XML"),
    "no joints": ("<robot name='x'><link name='a'/></robot>", "no joints"),
    "floating": (
        "<robot name='x'><link name='a'/><link name='b'/>"
        "<joint name='j' type='floating'><parent link='a'/><child link='b'/></joint></robot>",
        "floating",
    ),
    "no limits": (
        "<robot name='x'><link name='a'/><link name='b'/>"
        "<joint name='j' type='revolute'><parent link='a'/><child link='b'/></joint></robot>",
        "j.limit",
    ),
    "nan origin": (
        "<robot name='x'><link name='a'/><link name='b'/>"
        "<joint name='j' type='continuous'><parent link='a'/><child link='b'/><origin xyz='nan 0 0'/></joint></robot>",
        "j.origin",
    ),
    "zero axis": (
        "<robot name='x'><link name='a'/><link name='b'/>"
        "<joint name='j' type='continuous'><parent link='a'/><child link='b'/><axis xyz='0 0 0'/></joint></robot>",
        "j.axis",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_URDFS))
def test_bad_urdf_is_a_clear_error(tmp_path, capsys, case):
    text, message = BAD_URDFS[case]
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    assert main(["fk", str(path), "0"]) == 2
    err = capsys.readouterr().err
    assert "bad.urdf" in err and message in err and "Traceback" not in err


def test_unknown_tip_and_missing_file(tmp_path, capsys):
    path = random_urdf(tmp_path / "arm.urdf", np.random.default_rng(0), 6)
    with pytest.raises(fgcal.InputError, match="no link 'hand'"):
        fgcal.load_robot(path, tip="hand")
    assert main(["export", str(tmp_path / "missing.urdf"), "--urdf", str(tmp_path / "x.urdf")]) == 2
    assert "file not found" in capsys.readouterr().err
    assert main(["export", "abb_irb120", "--urdf", str(tmp_path / "x.txt")]) == 2
    assert "must end in .urdf" in capsys.readouterr().err


def test_urdf_robot_simulated_and_calibrated_end_to_end(tmp_path):
    """The seed cell with its robot given as URDF (the bundled KR 125/2 exported): simulated
    with fgcal's simulator (its truth perturbs the URDF parameters: origin corrections,
    offsets, compliances), calibrated with the tracker formulation, scored on the truth."""
    from conftest import SEED_CELL, calibrate

    from fgcal.calibration.config import CalibrationConfig
    from fgcal.simulation.simulate import simulate

    export_urdf(fgcal.load_robot("kuka_kr125_2"), tmp_path / "kr125.urdf")
    cell = SEED_CELL.read_text().replace("robot: kuka_kr125_2", "robot: kr125.urdf")
    (tmp_path / "cell.yaml").write_text(cell)
    simulate(tmp_path / "cell.yaml", tmp_path / "sim", seed=2, design="space_filling", n_configurations=120)
    truth = yaml.safe_load((tmp_path / "sim" / "truth" / "ground_truth.yaml").read_text())["parameters"]
    assert "tx2" in truth and "rx3" in truth and "alpha2" not in truth
    result = calibrate(CalibrationConfig.defaults(tmp_path / "sim", formulation="tracker"))
    assert result.truth is not None
    before, after = result.validation["before"]["tool_point"].rms, result.validation["after"]["tool_point"].rms
    predicted = result.prediction.rms
    assert after < before / 100, (before, after)
    assert after <= 1.5 * predicted, (after, predicted)
    assert any(name.startswith(("tx", "rx", "ry")) for name in result.identifiability.identifiable)


def test_a_cell_and_its_dataset_name_the_urdfs_tip_link(tmp_path, capsys):
    """Issue 22, item 8: ``robot: {file: arm.urdf, tip: LINK}`` names the tip of a URDF with
    several leaf links in a cell, and the simulated dataset's header carries it, so the dataset
    loads the same chain. (Issue 28: without a tip, such a URDF is a tree with its leaves as
    named tips.)"""
    from fgcal.data.dataset import load_dataset
    from fgcal.simulation.cell import load_cell

    text = random_urdf(tmp_path / "src.urdf", np.random.default_rng(3), 6).read_text()
    (tmp_path / "arm.urdf").write_text(text.replace('<link name="tool0"/>', "").split('<joint name="tool0_joint"')[0]
                                       + "</robot>")  # fmt: skip
    tree = fgcal.load_robot(tmp_path / "arm.urdf")
    assert len(tree.tip_names) > 1 and "flange" in tree.tip_names, tree.tip_names
    cell = yaml.safe_load((REPO / "datasets" / "cells" / "irb120_tracker.yaml").read_text())
    cell["robot"] = {"file": "arm.urdf", "tip": "flange"}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    assert load_cell(tmp_path / "cell.yaml").robot.n_joints == 6
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "data"), "--n", "20"]) == 0
    header = yaml.safe_load((tmp_path / "data" / "dataset.yaml").read_text())
    assert header["robot"] == {"file": "robot.urdf", "tip": "flange"}  # copied into the dataset
    dataset = load_dataset(tmp_path / "data")
    q = dataset.q[:3]
    np.testing.assert_allclose(dataset.robot.fk(q), fgcal.load_robot(tmp_path / "arm.urdf", tip="flange").fk(q))
    cell["robot"] = {"file": "arm.urdf", "tip": "ghost"}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    assert main(["simulate", str(tmp_path / "cell.yaml"), "--out", str(tmp_path / "other")]) == 2
    assert "no link 'ghost'" in capsys.readouterr().err


def test_a_deep_urdf_is_read_without_recursion(tmp_path):
    """Three thousand fixed adapters before one revolute joint (deeper than Python's recursion
    limit, which a recursive walk hit): read, and its FK adds the adapters up."""
    n = 3000
    links = "".join(f"<link name='l{i}'><inertial><mass value='0.001'/></inertial></link>" for i in range(n + 1))
    joints = "".join(
        f"<joint name='f{i}' type='fixed'><parent link='l{i}'/><child link='l{i + 1}'/><origin xyz='0.0001 0 0'/>"
        "</joint>"
        for i in range(n)
    )
    arm = (
        f"<robot name='deep'>{links}<link name='tool0'/>{joints}<joint name='j' type='revolute'>"
        f"<parent link='l{n}'/><child link='tool0'/><axis xyz='0 0 1'/>"
        "<limit lower='-3' upper='3' effort='1' velocity='1'/></joint></robot>"
    )
    (tmp_path / "deep.urdf").write_text(arm)
    robot = fgcal.load_robot(tmp_path / "deep.urdf")
    np.testing.assert_allclose(robot.fk(np.array([0.5]))[:3, 3], [n * 1e-4, 0, 0], atol=1e-9)
