"""The calibrated kinematics of a Universal Robots arm in the layout of the UR ROS 2
description's ``default_kinematics.yaml`` (``kinematics_parameters_file`` of ur_description).

That description builds the arm as ``base_link -> base_link_inertia`` (Rz(pi): the controller's
Base frame) and six revolute joints about their frames' z axes, each placed by ``x y z roll pitch
yaw`` in its parent link (shoulder, upper_arm, forearm, wrist_1, wrist_2, wrist_3); then fixed
joints ``wrist_3_link -> flange`` (rpy 0 -pi/2 -pi/2) and ``flange -> tool0`` (rpy pi/2 pi pi/2).

Each joint frame here is the calibrated joint's frame (fgcal.model.urdf_export.joint_frames: on its
axis, z along it, the joint offset folded in; a DH joint's moved along the axis by its d, where
UR's link frames and meshes are), expressed in the controller's base frame placed as
program filtering places it (fgcal.data.program_filter.controller_frame). The last joint's frame is
the calibrated flange (UR's DH frame 6; tool0 is it turned by pi about z, as in the nominal
description); the layout can hold that only if the calibrated flange is square to axis 6, and
what it cannot hold is reported.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..core.se3 import inverse, pose_from_xyz_rpy, rpy_from_rotation, so3_exp
from ..model.joints import DHJoint
from ..model.robot import Robot
from ..model.urdf_export import clean, is_tree, joint_frames
from .program_filter import controller_frame

JOINTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
# wrist_3_link -> tool0 in the UR description: the flange (0, -pi/2, -pi/2), then tool0 (pi/2, pi, pi/2).
WRIST_TO_TOOL0 = pose_from_xyz_rpy([0, 0, 0], [0, -np.pi / 2, -np.pi / 2]) @ pose_from_xyz_rpy(
    [0, 0, 0], [np.pi / 2, np.pi, np.pi / 2]
)


@dataclass(frozen=True)
class URKinematics:
    document: dict  # the YAML document (SI: m, rad)
    joint_frames: np.ndarray  # (6, 4, 4) each joint frame in the controller's base frame, q = 0
    tool0_tilt_rad: float  # what the layout cannot hold of the calibrated flange
    tool0_offset_m: float


def ur_kinematics(robot: Robot, nominal: Robot) -> URKinematics:
    """The document for ``robot`` (calibrated), the controller's base frame fitted against
    ``nominal``. A 6-axis arm of revolute joints, each turning with its joint value (direction +1)."""
    if is_tree(robot) or robot.n_joints != 6 or robot.prismatic.any() or np.any(robot.directions != 1):
        raise InputError(
            None, "--ur-kinematics", f"{robot.name} is not laid out as a UR arm (six revolute joints, directions +1)"
        )
    rigid = robot.with_model("DH,s")  # a kinematics file cannot bend: the compliances stay in the sidecar
    frames = joint_frames(rigid)
    _check_ur_layout(robot, frames)
    base = controller_frame(rigid, nominal)
    joints = inverse(base) @ frames["joints"]  # in the controller's base frame
    axes = frames["axes"]
    joints = np.array([_z_along(J, axis) for J, axis in zip(joints, axes, strict=True)])
    # UR's link frames sit where the DH link's offset d ends (the shoulder at the base's height):
    # moved along their axes there, the description's meshes stay on their links.
    values = rigid.nominal_parameters()
    for i, joint in enumerate(rigid.joints):
        if isinstance(joint, DHJoint):
            joints[i] = joints[i] @ pose_from_xyz_rpy([0, 0, values[f"d{i + 1}"]], [0, 0, 0])
    # The wrist_3 link frame is UR's DH frame 6, fgcal's flange (the description's tool0 is it
    # turned by pi about z, WRIST_TO_TOOL0, for the calibrated arm as for the nominal one).
    wanted = inverse(base) @ frames["flange"]
    last = joints[5]
    tilt = float(np.arctan2(np.linalg.norm(np.cross(wanted[:3, 2], last[:3, 2])), wanted[:3, 2] @ last[:3, 2]))
    along = last[:3, 2] @ (wanted[:3, 3] - last[:3, 3])
    offset = float(np.linalg.norm(wanted[:3, 3] - last[:3, 3] - along * last[:3, 2]))
    # The wrist_3 frame: on axis 6, z along it, turned about it and moved along it to match.
    turn = np.arctan2(last[:3, 1] @ wanted[:3, 0], last[:3, 0] @ wanted[:3, 0])
    spin = pose_from_xyz_rpy([0, 0, along], [0, 0, turn])
    joints[5] = last @ spin
    entries = {}
    parent = np.eye(4)
    for name, J in zip(JOINTS, joints, strict=True):
        local = inverse(parent) @ J
        xyz, rpy = local[:3, 3], rpy_from_rotation(local[:3, :3])
        entries[name] = {
            k: clean(v) for k, v in zip(("x", "y", "z", "roll", "pitch", "yaw"), [*xyz, *rpy], strict=True)
        }
        parent = J
    digest = hashlib.sha256(repr(sorted((k, tuple(v.values())) for k, v in entries.items())).encode()).hexdigest()
    document = {"kinematics": {**entries, "hash": f"fgcal_{digest[:16]}"}}
    return URKinematics(document, joints, tilt, offset)


UR_AXES_DEG = 2.0  # how far from parallel or square the UR layout's axes may be


def _check_ur_layout(robot: Robot, frames: dict) -> None:
    """A UR arm: axes 2, 3 and 4 parallel, axis 1 square to 2, 5 square to 4, 6 square to 5."""
    axes = np.einsum("nij,nj->ni", frames["joints"][:, :3, :3], frames["axes"])  # in W
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    tolerance = np.sin(np.radians(UR_AXES_DEG))
    parallel = all(np.linalg.norm(np.cross(axes[1], axes[k])) < tolerance for k in (2, 3))
    square = all(abs(axes[a] @ axes[b]) < tolerance for a, b in ((0, 1), (3, 4), (4, 5)))
    if not (parallel and square):
        raise InputError(
            None, "--ur-kinematics", f"{robot.name} is not laid out as a UR arm (axes 2, 3 and 4 parallel; 1, 5 and "
            "6 square to their neighbours): the UR description cannot hold it",
        )  # fmt: skip


def _z_along(J: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The joint frame turned so that its z is the joint axis (given in the frame)."""
    axis = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    if np.allclose(axis, z, atol=1e-15):
        return J
    angle = np.arccos(np.clip(axis @ z, -1.0, 1.0))
    cross = np.cross(z, axis)
    direction = cross / np.linalg.norm(cross) if np.linalg.norm(cross) > 1e-15 else np.array([1.0, 0.0, 0.0])
    R = so3_exp(direction * angle)  # takes z onto the axis
    out = J.copy()
    out[:3, :3] = J[:3, :3] @ R
    return out


def residual_text(result: URKinematics) -> str:
    return (
        f"{np.degrees(result.tool0_tilt_rad) * 1e3:.3f} mdeg, {result.tool0_offset_m * 1e3:.4f} mm"
        if result.tool0_tilt_rad > 1e-9 or result.tool0_offset_m > 1e-9
        else "none"
    )
