"""Rigid-body helpers on stacked arrays (leading axes are configurations).

Poses are 4x4 homogeneous matrices; twists follow GTSAM's order ``[omega, v]``.
"""

from __future__ import annotations

import numpy as np

_AXIS = {"x": 0, "y": 1, "z": 2}


def skew(w: np.ndarray) -> np.ndarray:
    """Return ``[w]x`` for ``w`` of shape (..., 3)."""
    w = np.asarray(w, dtype=float)
    out = np.zeros((*w.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -w[..., 2], w[..., 1]
    out[..., 1, 0], out[..., 1, 2] = w[..., 2], -w[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -w[..., 1], w[..., 0]
    return out


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis with broadcasting (much faster than np.cross on
    small stacked arrays, which dominates the Jacobian's cost)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(b)), dtype=np.result_type(a, b))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def rot_axis(axis: str, angle_rad: float) -> np.ndarray:
    """3x3 rotation about the principal ``axis`` ('x', 'y' or 'z')."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    i = _AXIS[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    rot = np.eye(3)
    rot[j, j], rot[j, k], rot[k, j], rot[k, k] = c, -s, s, c
    return rot


def so3_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices from rotation vectors (..., 3), in rad."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = skew(r)
    small = theta < 1e-8
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    return np.eye(3) + a * k + b * (k @ k)


def so3_log(rot: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), in rad, of rotation matrices (..., 3, 3).

    The angle comes from atan2 (precise everywhere, unlike arccos near 0 and pi). Near pi,
    where the antisymmetric part vanishes, the axis comes from the symmetric part,
    ``(R + R^T)/2 - cos(theta) I = (1 - cos(theta)) a a^T``, signed by the antisymmetric part.
    """
    rot = np.asarray(rot, dtype=float)
    vee = np.stack(
        [rot[..., 2, 1] - rot[..., 1, 2], rot[..., 0, 2] - rot[..., 2, 0], rot[..., 1, 0] - rot[..., 0, 1]],
        axis=-1,
    )
    sin = np.linalg.norm(vee, axis=-1) / 2.0
    cos = (np.trace(rot, axis1=-2, axis2=-1) - 1.0) / 2.0
    theta = np.arctan2(sin, cos)
    small = sin < 1e-9
    # theta / (2 sin theta) -> 1/2 (1 + theta^2 / 6) as theta -> 0
    scale = np.where(small, 0.5 + theta**2 / 12.0, theta / (2.0 * np.where(small, 1.0, sin)))
    out = scale[..., None] * vee
    near_pi = (sin < 1e-3) & (cos < 0)
    if np.any(near_pi):
        R = rot[near_pi]
        c = cos[near_pi][:, None, None]
        B = (R + np.swapaxes(R, -1, -2)) / 2.0 - c * np.eye(3)
        k = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        rows = np.arange(len(k))
        axis = B[rows, :, k] / np.sqrt(np.clip(B[rows, k, k] * (1.0 - c[:, 0, 0]), 1e-300, None))[:, None]
        sign = np.where(np.sum(axis * vee[near_pi], axis=-1) < 0, -1.0, 1.0)
        out[near_pi] = (sign * theta[near_pi])[:, None] * axis
    return out


def so3_left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``d Exp(r) = [J_l(r) dr]x Exp(r)``."""
    r = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = skew(r)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - theta**2 / 120.0, (t - np.sin(t)) / t**3)
    return np.eye(3) + a * k + b * (k @ k)


def pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Assemble 4x4 poses from rotations (..., 3, 3) and translations (..., 3)."""
    rotation = np.asarray(rotation, dtype=float)
    out = np.zeros((*rotation.shape[:-2], 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def pose_from_xyz_rpy(xyz: np.ndarray, rpy_rad: np.ndarray) -> np.ndarray:
    """Pose ``Tx Ty Tz Rz(yaw) Ry(pitch) Rx(roll)``: the robotics convention for fixed frames."""
    roll, pitch, yaw = rpy_rad
    return pose(rot_axis("z", yaw) @ rot_axis("y", pitch) @ rot_axis("x", roll), xyz)


def rpy_from_rotation(rot: np.ndarray) -> np.ndarray:
    """Inverse of the rotation in :func:`pose_from_xyz_rpy`, (roll, pitch, yaw) in rad.

    Yaw first, then pitch and roll from the rotation with the yaw removed: near pitch = +-90
    deg (gimbal lock) roll and yaw turn about one axis and yaw is poorly determined, but the
    roll computed after it takes up its error, so the angles reproduce the rotation to
    rounding everywhere (at exact gimbal lock yaw is 0 and roll carries the whole turn).
    """
    yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    # Rows of Rz(-yaw) R = Ry(pitch) Rx(roll) = [[cp, sp sr, sp cr], [0, cr, -sr], [-sp, cp sr, cp cr]].
    pitch = float(np.arctan2(-rot[2, 0], c * rot[0, 0] + s * rot[1, 0]))
    roll = float(np.arctan2(s * rot[0, 2] - c * rot[1, 2], c * rot[1, 1] - s * rot[0, 1]))
    return np.array([roll, pitch, yaw])


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of stacked rigid transforms."""
    rot_t = np.swapaxes(T[..., :3, :3], -1, -2)
    return pose(rot_t, -(rot_t @ T[..., :3, 3:4])[..., 0])


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply poses (..., 4, 4) to points (..., 3)."""
    return (T[..., :3, :3] @ points[..., None])[..., 0] + T[..., :3, 3]


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising |R source + t - target| over points (N, 3)."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    H = (source - mu_s).T @ (target - mu_t)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


def quaternion_rotation(wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrix of the quaternion (qw, qx, qy, qz), normalised first."""
    w, x, y, z = np.asarray(wxyz, dtype=float) / np.linalg.norm(wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_quaternion(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion (qw, qx, qy, qz), qw >= 0, of a rotation matrix (via its rotation vector)."""
    rotvec = so3_log(rot)
    angle = np.linalg.norm(rotvec)
    axis = rotvec / angle if angle > 0 else np.zeros(3)
    return np.array([np.cos(angle / 2), *(np.sin(angle / 2) * axis)])
