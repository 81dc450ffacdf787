"""Issue 37: a robot's model compiled once (fgcal.model.chain_model), as Pinocchio separates
Model from Data. Its constant tables are built once per robot, whatever it evaluates; no table
is cached on an object's identity; the mass scales' Jacobian columns (now the kernel's) match
central differences on a serial chain; an evaluation is one buffer the kernels read whole."""

from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import random_parameters

import fgcal
from fgcal.core.se3 import so3_exp, so3_left_jacobian
from fgcal.model import chain_kernel, chain_model, ets, kinematics

ROOT = Path(__file__).parent.parent


def _counting(monkeypatch: pytest.MonkeyPatch, module: object, name: str) -> list:
    """Replace ``module.name`` by a wrapper that records each call's first argument."""
    calls: list = []
    original = getattr(module, name)

    def counted(*args, **kwargs):
        calls.append(args[0])
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_a_robot_builds_its_constant_tables_once(monkeypatch):
    """FK and Jacobians of several parameter sets, on every tip, poses and points, build the
    chain's tables (the compiled model and its element tables) exactly once per robot."""
    loaded = fgcal.load_robot("dual_arm_torso")
    robot = loaded.with_model("DH,s,e,h")  # a new robot: nothing built yet
    builds = _counting(monkeypatch, chain_model, "build")
    layouts = _counting(monkeypatch, ets, "layout")
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (3, robot.n_joints))
    wrt = [*robot.parameter_names[:20], "mass.arms", "q1", "q5"]
    for _ in range(3):
        params = random_parameters(robot, rng)
        vector = robot.parameter_vector(params)
        for tip in [*robot.tip_names, "tool"]:
            robot.fk(q, params, tip=None if tip == "tool" else tip)
            robot.jacobian(q[0], wrt, params, frame=tip)
            robot.jacobian(q, wrt, params, frame=tip, point=[0.0, 0.1, 0.2])
            data = kinematics.forward(robot, vector, q)
            kinematics.spatial_jacobian(robot, data, ["q2", "kz1"], frame=tip)
            kinematics.path_joints(robot, tip)
        robot.fk_tool(q, params)
        robot.reach_m(vector, tip=robot.tip_names[1])
    assert builds == [robot] and len(layouts) == 1
    # Another robot (another model of the same file) has its own, built once too.
    other = robot.with_model("DH,s")
    other.fk(q)
    other.fk(q, tip=robot.tip_names[1])
    assert builds == [robot, other] and len(layouts) == 2
    assert robot.compiled is not other.compiled


def test_no_table_is_cached_on_an_objects_identity():
    """The tables live in each robot's compiled model: nothing in fgcal/ or factors/ keys a
    cache on id() (an entry whose object died may be found again by a new one's id)."""
    calls = []
    for path in [*sorted((ROOT / "fgcal").rglob("*.py")), *sorted((ROOT / "factors").rglob("*.py"))]:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "id":
                calls.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not calls, f"id() in {calls}"


def test_the_jacobian_entries_are_memoised_by_the_names_themselves():
    robot = fgcal.load_robot("abb_irb120")
    names = ["q1", "theta2", "kz2"]
    first = robot.compiled.columns(names)
    assert robot.compiled.columns(list(names)) is first  # an equal list, another object
    assert robot.compiled.columns(tuple(names)) is first
    assert robot.compiled.columns(["q1", "theta2"]) is not first


def _serial_with_mass_groups() -> fgcal.Robot:
    """The IRB 120 with its forearm and wrist (links 3 to 6) as one body group."""
    robot = fgcal.load_robot("abb_irb120").with_tool(np.eye(4), payload_mass=2.0, payload_com=[0.0, 0.01, 0.05])
    return replace(robot, mass_groups=(("forearm", (2, 3, 4, 5)), ("upper", (1,))))


@pytest.mark.parametrize("frame", ["flange", "tool"])
def test_mass_scale_columns_match_central_differences_on_a_serial_chain(frame):
    """d pose / d mass.{group}: the gravity moments' rate through every compliance on the path,
    the compiled kernel's one implementation, against central differences of FK; zero without
    compliances (a mass scale moves the robot only through them)."""
    robot = _serial_with_mass_groups()
    rng = np.random.default_rng(7)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (4, robot.n_joints))
    params = {f"k{axis}{j}": float(rng.uniform(1e-5, 5e-5)) for axis in "xyz" for j in range(1, 7)}
    params |= {"mass.forearm": 1.2, "mass.upper": 0.9}
    point = np.array([0.02, -0.03, 0.1])
    wrt = ["mass.forearm", "mass.upper"]
    J_pose = robot.jacobian(q, wrt, params, frame=frame)
    J_point = robot.jacobian(q, wrt, params, frame=frame, point=point)
    for col, name in enumerate(wrt):
        step = 1e-5
        up = kinematics.frame_pose(robot, _forward(robot, params | {name: params[name] + step}, q), frame)
        down = kinematics.frame_pose(robot, _forward(robot, params | {name: params[name] - step}, q), frame)
        point_rate = ((up[:, :3, :3] - down[:, :3, :3]) @ point + up[:, :3, 3] - down[:, :3, 3]) / (2 * step)
        np.testing.assert_allclose(J_point[:, :, col], point_rate, rtol=1e-6, atol=1e-12 * np.abs(point_rate).max())
        # The body twist: R^T dR (angular) and R^T dp (linear), by the same differences.
        pose = kinematics.frame_pose(robot, _forward(robot, params, q), frame)
        d_rotation = np.swapaxes(pose[:, :3, :3], 1, 2) @ (up[:, :3, :3] - down[:, :3, :3]) / (2 * step)
        omega = np.stack([d_rotation[:, 2, 1], d_rotation[:, 0, 2], d_rotation[:, 1, 0]], axis=1)
        v = np.einsum("nji,nj->ni", pose[:, :3, :3], (up[:, :3, 3] - down[:, :3, 3]) / (2 * step))
        numeric = np.concatenate([omega, v], axis=1)
        assert np.linalg.norm(J_pose[:, :, col] - numeric) <= 1e-6 * np.linalg.norm(numeric)
        assert np.linalg.norm(J_point[:, :, col]) > 1e-6  # the scale does move the frame
    rigid = {name: value for name, value in params.items() if name[0] != "k"}
    assert np.all(robot.jacobian(q, wrt, rigid, frame=frame) == 0.0)


def _forward(robot: fgcal.Robot, params: dict, q: np.ndarray) -> kinematics.KinematicsData:
    return kinematics.forward(robot, robot.parameter_vector(params), q)


def test_an_evaluation_is_one_buffer_and_a_subset_is_its_rows():
    robot = fgcal.load_robot("dual_arm_torso")
    rng = np.random.default_rng(2)
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (5, robot.n_joints))
    params = robot.parameter_vector(random_parameters(robot, rng))
    data = kinematics.forward(robot, params, q)
    for name in chain_model.EVALUATION:
        array = getattr(data, name)
        if name.startswith("frames"):
            assert np.shares_memory(array, data.buffer)
        else:  # the gravity arrays: copies, so that keeping one does not keep the frames alive
            assert not np.shares_memory(array, data.buffer) and not array.flags.writeable
            np.testing.assert_array_equal(array, data.model.array(data.buffer, name, len(q)))
    assert data.frames.shape == data.frames_rigid.shape == (len(robot.chain.elements) + 1, 5, 3, 4)
    rows = np.array([3, 0])
    subset, direct = data.subset(rows), kinematics.forward(robot, params, q[rows])
    for name in chain_model.EVALUATION:
        np.testing.assert_array_equal(getattr(subset, name), getattr(direct, name))
    wrt = ["q1", "theta3", "kz1", "mass.arms"]
    np.testing.assert_array_equal(
        kinematics.jacobian(robot, subset, wrt, "right_hand"), kinematics.jacobian(robot, direct, wrt, "right_hand")
    )


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-7, 1e-3, 0.5, 3.0])
def test_the_kernels_rotation_vectors_are_se3s(scale):
    """The kernel's Exp(r) and J_l(r) (the base and tool perturbations) equal fgcal.core.se3's,
    through the small-angle series too."""
    r = scale * np.array([0.3, -0.8, 0.5])
    rotation, left = np.empty((3, 3)), np.empty((3, 3))
    chain_kernel.rotation_vector(r, 0, False, rotation)
    chain_kernel.rotation_vector(r, 0, True, left)
    np.testing.assert_allclose(rotation, so3_exp(r), rtol=0, atol=1e-15)
    np.testing.assert_allclose(left, so3_left_jacobian(r), rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    ("robot_name", "model", "frame", "point"),
    [("abb_irb120", "DH,s", "flange", None), ("abb_irb120", "DH,s,e", "tool", [0.01, -0.02, 0.1]),
     ("dual_arm_torso", "DH,s,e,h", None, None)],
)  # fmt: skip
def test_a_workspace_gives_what_forward_and_jacobian_give(robot_name, model, frame, point):
    """kinematics.forward_jacobian (one compiled call into a caller's Workspace, issue 37's
    single configuration) gives what forward() and jacobian() give, for every parameter and
    joint, on a pose or a point, with the motion history; each call overwrites the last. The
    same code compiled into another kernel: equal to rounding (contracted multiply-adds)."""
    robot = fgcal.load_robot(robot_name).with_model(model)
    frame = frame or robot.tip_names[1]
    rng = np.random.default_rng(3)
    vector = robot.parameter_vector(random_parameters(robot, rng))
    wrt = [*robot.parameter_names, *(f"q{j + 1}" for j in range(robot.n_joints))]
    work = kinematics.Workspace(robot, wrt, frame=frame, point=point, n_conf=2)
    for _ in range(2):
        q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (2, robot.n_joints))
        motion = rng.normal(size=(2, 2 * robot.n_joints)) if robot.history else None
        data = kinematics.forward(robot, vector, q, motion)
        expected = kinematics.jacobian(robot, data, wrt, frame=frame, point=point)
        got = kinematics.forward_jacobian(work, vector, q, motion)
        assert got is work.jacobian
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-14 * np.abs(expected).max())
        np.testing.assert_allclose(work.frames, data.frames, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(work.moments, data.moments, rtol=1e-12, atol=1e-14 * np.abs(data.moments).max())
    with pytest.raises(ValueError, match="workspace"):
        kinematics.forward_jacobian(work, vector, q[:1])
    with pytest.raises(ValueError, match="workspace"):
        kinematics.forward_jacobian(work, vector[:-1], q)
