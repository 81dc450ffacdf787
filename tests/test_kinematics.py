"""Forward kinematics against hand-worked poses; analytic Jacobians against central
finite differences (SPEC section 3: 1e-6 relative)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_parameters, random_urdf

import fgcal
from fgcal.core.se3 import so3_log
from fgcal.model import kinematics
from fgcal.model.motion import MotionHistory, features

# Flange axes at q = 0, worked by hand from the DH tables: both robots end with the flange
# z axis pointing forward (+x0) and its x axis pointing down.
R_FORWARD = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def test_kuka_zero_configuration_by_hand():
    # d1 = 0.865 up, a1 = 0.41 + a2 = 1.0 forward, a3 = 0.045 up, -d4 = 1.0 and -d6 = 0.21 forward.
    T = fgcal.load_robot("kuka_kr125_2").fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [0.41 + 1.0 + 1.0 + 0.21, 0.0, 0.865 + 0.045], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], R_FORWARD, atol=1e-12)


def test_kuka_joint1_direction_is_negative():
    # Joint 1 turns clockwise (direction -1): +90 deg brings the arm to -y.
    T = fgcal.load_robot("kuka_kr125_2").fk(np.array([np.pi / 2, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3], [0.0, -2.62, 0.91], atol=1e-12)


def test_irb120_zero_configuration_by_hand():
    # d1 = 0.29 up, a2 = 0.27 up (theta2 = -90), a3 = 0.07 up, d4 = 0.302 and d6 = 0.072 forward.
    T = fgcal.load_robot("abb_irb120").fk(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [0.302 + 0.072, 0.0, 0.29 + 0.27 + 0.07], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3], R_FORWARD, atol=1e-12)


def test_irb120_elbow_up_by_hand():
    # q3 = -90 deg swings the forearm from horizontal to pointing up: all lengths stack up.
    T = fgcal.load_robot("abb_irb120").fk(np.deg2rad([0, 0, -90, 0, 0, 0]))
    np.testing.assert_allclose(T[:3, 3], [-0.07, 0.0, 0.29 + 0.27 + 0.302 + 0.072], atol=1e-12)


def test_nominal_parameters_has_every_spec_name():
    robot = fgcal.load_robot("kuka_kr125_2")
    params = robot.nominal_parameters()
    kinds = ("theta", "d", "a", "alpha", "sx", "sy", "kx", "ky", "kz", "lm", "lv")
    expected = {f"{k}{i}" for i in range(1, 7) for k in kinds}
    expected |= {f"{p}.{k}" for p in ("base", "tool") for k in ("tx", "ty", "tz", "rx", "ry", "rz")}
    assert set(params) == expected
    assert params["a1"] == pytest.approx(0.41) and params["alpha1"] == pytest.approx(-np.pi / 2)
    assert all(params[f"{k}{i}"] == 0.0 for i in range(1, 7) for k in ("sx", "sy", "kx", "ky", "kz", "lm", "lv"))


def test_partial_parameters_and_batch_agree():
    robot = fgcal.load_robot("kuka_kr125_2")
    q = np.random.default_rng(3).uniform(-1, 1, (5, 6))
    batch = robot.fk(q, {"d1": 0.9})
    single = np.array([robot.fk(qi, {"d1": 0.9}) for qi in q])
    np.testing.assert_allclose(batch, single, atol=1e-14)
    np.testing.assert_allclose(batch[:, 2, 3] - robot.fk(q)[:, 2, 3], 0.035, atol=1e-12)


def test_models_agree_at_nominal_and_compliance_needs_dhse():
    robot = fgcal.load_robot("kuka_kr125_2")
    q = np.random.default_rng(4).uniform(-1, 1, (4, 6))
    for model in ("DH", "DH,s"):
        np.testing.assert_allclose(robot.with_model(model).fk(q), robot.fk(q), atol=1e-12)
    # Joint 2 carries the arm's weight about its own axis: torsion kz2 deflects the flange.
    bent = robot.fk(q, {"kz2": 1e-6})
    assert np.max(np.linalg.norm(bent[:, :3, 3] - robot.fk(q)[:, :3, 3], axis=1)) > 1e-3
    np.testing.assert_allclose(robot.with_model("DH,s").fk(q, {"kz2": 1e-6}), robot.fk(q), atol=1e-12)


@pytest.mark.parametrize("robot_name", ["kuka_kr125_2", "random_urdf"])
def test_gravity_moment_against_direct_sum(robot_name, tmp_path):
    """t_i = R_W_Bi^T sum_b (c_b - o_Bi) x m_b g, summed body by body from the frames."""
    robot = _load(robot_name, tmp_path).with_tool(np.eye(4), payload_mass=30.0, payload_com=[0.01, 0.02, 0.1])
    rng = np.random.default_rng(5)
    params = robot.parameter_vector(random_parameters(robot, rng))
    q = rng.uniform(-1, 1, (3, robot.n_joints))
    data = kinematics.forward(robot, params, q)
    chain = robot.chain
    for i in range(robot.n_joints):
        bend = data.frames_rigid[chain.bend[i]]
        total = np.zeros((3, 3))
        for b in range(i, robot.n_joints):
            frame = data.frames_rigid[chain.link_end[b]]
            com = frame[:, :3, :3] @ robot.coms[b] + frame[:, :3, 3]
            total += np.cross(com - bend[:, :3, 3], robot.masses[b] * robot.gravity)
        flange = data.frames_rigid[chain.flange]
        com = flange[:, :3, :3] @ robot.payload_com + flange[:, :3, 3]
        total += np.cross(com - bend[:, :3, 3], robot.payload_mass * robot.gravity)
        expected = np.einsum("nji,nj->ni", bend[:, :3, :3], total)
        np.testing.assert_allclose(data.moments[:, 3 * i : 3 * i + 3], expected, rtol=1e-12, atol=1e-9)


def _fd_columns(robot, q, params, name, frame, point, step, motion=None):
    def pose(h):
        if name.startswith("q"):
            qq = q.copy()
            qq[:, int(name[1:]) - 1] += h
            return robot._frame(qq, params, frame, motion)
        shifted = dict(params)
        shifted[name] += h
        return robot._frame(q, shifted, frame, motion)

    T0, Tp, Tm = pose(0.0), pose(step), pose(-step)
    R0t = np.swapaxes(T0[:, :3, :3], 1, 2)
    d_rot = (so3_log(R0t @ Tp[:, :3, :3]) - so3_log(R0t @ Tm[:, :3, :3])) / (2 * step)
    d_pos = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * step)
    twist = np.concatenate([d_rot, np.einsum("nij,nj->ni", R0t, d_pos)], axis=1)
    p_plus = Tp[:, :3, :3] @ point + Tp[:, :3, 3]
    p_minus = Tm[:, :3, :3] @ point + Tm[:, :3, 3]
    return twist, (p_plus - p_minus) / (2 * step)


def _relative_error(analytic, numeric):
    scale = np.linalg.norm(numeric)
    return np.linalg.norm(analytic - numeric) / (scale if scale > 1e-9 else 1.0)


def _load(robot_name: str, tmp_path) -> fgcal.Robot:
    """A bundled robot, or a random 7-joint URDF (joint 4 prismatic with 'prismatic')."""
    if robot_name.startswith("random_urdf"):
        prismatic = 4 if robot_name.endswith("prismatic") else None
        return fgcal.load_robot(random_urdf(tmp_path / "arm.urdf", np.random.default_rng(7), 7, prismatic))
    return fgcal.load_robot(robot_name)


@pytest.mark.parametrize("robot_name", ["kuka_kr125_2", "ur10e", "random_urdf", "random_urdf_prismatic"])
@pytest.mark.parametrize("frame", ["flange", "tool"])
@pytest.mark.parametrize("model", ["DH,s,e", "DH,s,e,h"])
def test_jacobian_matches_central_differences(robot_name, frame, model, tmp_path):
    rng = np.random.default_rng(11)
    robot = (
        _load(robot_name, tmp_path)
        .with_tool(
            np.array([[0, -1, 0, 0.05], [1, 0, 0, 0.02], [0, 0, 1, 0.15], [0, 0, 0, 1.0]]),
            payload_mass=20.0,
            payload_com=[0.01, 0.0, 0.08],
        )
        .with_model(model)
    )
    params = random_parameters(robot, rng)
    q = rng.uniform(-2.0, 2.0, (3, robot.n_joints))
    # The features of configurations reached by random moves (fgcal.model.motion).
    motion = features(q, MotionHistory(q - rng.uniform(-0.5, 0.5, q.shape), rng.uniform(0.2, 1.0, 3)))
    point = np.array([0.1, -0.2, 0.3])
    wrt = robot.parameter_names + [f"q{i}" for i in range(1, robot.n_joints + 1)]
    J_pose = robot.jacobian(q, wrt, params, frame=frame, motion=motion)
    J_point = robot.jacobian(q, wrt, params, frame=frame, point=point, motion=motion)
    assert J_pose.shape == (3, 6, len(wrt)) and J_point.shape == (3, 3, len(wrt))
    moments = kinematics.forward(robot, robot.parameter_vector(params), q).moments
    worst = {}
    for col, name in enumerate(wrt):
        step = 1e-6
        if name[0] == "k":
            # Step the compliance so that the deflection angle k * t changes by about 1e-6 rad.
            component = 3 * (int(name[2:]) - 1) + "xyz".index(name[1])
            step = 1e-6 / max(1.0, np.abs(moments[:, component]).max())
        twist, point_rate = _fd_columns(robot, q, params, name, frame, point, step, motion)
        worst[name] = max(_relative_error(J_pose[:, :, col], twist), _relative_error(J_point[:, :, col], point_rate))
    bad = {k: v for k, v in worst.items() if v > 1e-6}
    assert not bad, f"Jacobian columns off by more than 1e-6 relative: {bad}"
    # Compliance enters through the moment, geometric parameters through it too (k != 0).
    assert np.linalg.norm(J_point[:, :, wrt.index("kz2")]) > 1.0
    # The motion terms move the frame only in the model that has them.
    assert (np.linalg.norm(J_point[:, :, wrt.index("lm2")]) > 0.1) == (model == "DH,s,e,h")


def test_tool_parameters_do_not_move_the_flange():
    robot = fgcal.load_robot("kuka_kr125_2")
    J = robot.jacobian(np.zeros(6), ["tool.tx", "tool.rz"], frame="flange")
    assert np.all(J == 0.0)


def test_bad_joint_angles_are_clear_errors():
    robot = fgcal.load_robot("kuka_kr125_2")
    with pytest.raises(fgcal.InputError, match="6 joints"):
        robot.fk(np.zeros(5))
    with pytest.raises(fgcal.InputError, match="finite"):
        robot.fk(np.array([0, 0, np.nan, 0, 0, 0]))
    with pytest.raises(fgcal.InputError, match="unknown parameter"):
        robot.fk(np.zeros(6), {"theta7": 0.1})
    with pytest.raises(fgcal.InputError, match="finite"):
        robot.fk(np.zeros(6), {"d2": float("nan")})


def test_arrays_short_of_the_chain_are_refused_not_read_past():
    """The compiled kernel does not check its bounds: the callers do."""
    from fgcal.model import ets

    robot = fgcal.load_robot("abb_irb120")
    params = robot.parameter_vector()
    with pytest.raises(fgcal.InputError, match="point"):
        robot.jacobian(np.zeros(6), ["q1"], point=[0.1, 0.2])
    with pytest.raises(ValueError, match="joint values"):
        kinematics.forward(robot, params, np.zeros((2, 5)))
    with pytest.raises(ValueError, match="parameters"):
        kinematics.forward(robot, params[:-1], np.zeros((2, 6)))
    with pytest.raises(ValueError, match="moments"):
        ets.evaluate(robot.chain.elements, params, np.zeros((2, 6)), np.zeros((2, 2)))
