"""Closed-form IK of a 6-axis arm with a spherical wrist, as a controller solves its nominal
model: every branch (shoulder in front or behind, elbow, wrist flip) of a flange pose at once.

The arm is written as a product of exponentials of the joints' twists at the zero pose
(Murray, Li and Sastry, ch. 3), ``T(q) = exp(xi_1 q_1) ... exp(xi_6 q_6) T(0)``, read off the
compiled model's joint Jacobian at q = 0, so that every convention (DH, Craig, URDF joints)
takes one path. With axes 4-6 meeting at the wrist centre c:

- joint 1 turns the plane joints 2 and 3 move the wrist centre in (at the shoulder's offset
  from axis 1) through the wrist centre, in front or behind (exact where axis 2 is
  perpendicular to axis 1, as on ABB, KUKA and PUMA arms; a start otherwise);
- joint 3 from the wrist centre's distance to a point on axis 2 (Paden-Kahan 3), joint 2 then
  turns it onto the target (Paden-Kahan 1);
- joints 4 and 5 turn axis 6 onto its target direction (Paden-Kahan 2), joint 6 the rest.

The solutions are exact on the model the twists came from: a rigid chain (the controller's
nominal model). A caller checks them by FK, and polishes or refuses what does not close.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.se3 import inverse

SPHERICAL_TOL_M = 1e-9  # axes 4, 5 and 6 meet within this: a spherical wrist


@dataclass(frozen=True)
class WristArm:
    """The twists of a 6-axis arm at its zero pose, in its base frame (m)."""

    axis: np.ndarray  # (6, 3) unit joint axes
    point: np.ndarray  # (6, 3) a point on each axis
    centre: np.ndarray  # (3,) the wrist centre at the zero pose
    T_base_flange0: np.ndarray  # (4, 4) the flange at the zero pose


def zero_pose_axes(robot) -> tuple[np.ndarray, np.ndarray] | None:
    """Each revolute joint's unit axis (n, 3) and a point on it (n, 3) at the zero pose, in the
    base frame (m), read off the rigid flange Jacobian; None with a prismatic joint or a joint
    that does not move the flange."""
    n = robot.n_joints
    if np.any(robot.prismatic):
        return None
    zero = np.zeros((1, n))
    J = robot.jacobian(zero, [f"q{i + 1}" for i in range(n)], frame="flange")[0]  # body rows [omega, v]
    T0 = robot.fk(zero)[0]
    omega, v = J[:3].T, J[3:].T  # (n, 3) in the flange frame
    length = np.linalg.norm(omega, axis=1)
    if np.any(length < 1e-12):
        return None
    omega, v = omega / length[:, None], v / length[:, None]
    # A point x on a revolute axis does not move: v + omega x x = 0, so x = omega x v.
    R0, p0 = T0[:3, :3], T0[:3, 3]
    return omega @ R0.T, np.cross(omega, v) @ R0.T + p0


def wrist_arm(robot) -> WristArm | None:
    """The twists of ``robot`` (fgcal.model.robot.Robot, its rigid nominal chain); None when it
    is not a 6-axis arm of revolute joints with a spherical wrist."""
    axes = zero_pose_axes(robot) if robot.n_joints == 6 else None
    if axes is None:
        return None
    axis, point = axes
    # The wrist centre is the point on every wrist axis: (I - a a^T)(c - p) = 0 for axes 4-6.
    A = np.vstack([np.eye(3) - np.outer(axis[j], axis[j]) for j in (3, 4, 5)])
    b = np.concatenate([(np.eye(3) - np.outer(axis[j], axis[j])) @ point[j] for j in (3, 4, 5)])
    c = np.linalg.lstsq(A, b, rcond=None)[0]
    if np.linalg.norm(A @ c - b) > SPHERICAL_TOL_M:
        return None
    return WristArm(axis, point, c, robot.fk(np.zeros(6)))


def branches(arm: WristArm, T_base_flange: np.ndarray) -> np.ndarray:
    """Joints (N, 8, 6) of every branch for flange poses (N, 4, 4), rad in (-pi, pi]; NaN rows
    where a branch does not exist (beyond reach). Order: joint 1 in front/behind, then the two
    elbows, then the two wrists."""
    g = T_base_flange @ inverse(arm.T_base_flange0)  # = exp(xi_1 q_1) ... exp(xi_6 q_6)
    N = len(g)
    centre = g[:, :3, :3] @ arm.centre + g[:, :3, 3]  # where the wrist centre must go
    out = np.full((N, 8, 6), np.nan)
    k = 0
    for q1 in _shoulder(arm, centre):
        R1 = rotation(arm.axis[0], q1)
        # The wrist centre with joint 1 undone: what joints 2 and 3 must reach.
        target = np.einsum("nji,nj->ni", R1, centre - arm.point[0]) + arm.point[0]
        reach = np.linalg.norm(target - arm.point[1], axis=1)
        for q3 in _turns_to_distance(arm.axis[2], arm.point[2], arm.centre, arm.point[1], reach):
            R3 = rotation(arm.axis[2], q3)
            elbow = np.einsum("nij,j->ni", R3, arm.centre - arm.point[2]) + arm.point[2]
            q2 = _turn(arm.axis[1], arm.point[1], elbow, target)
            R123 = R1 @ rotation(arm.axis[1], q2) @ R3
            wrist = np.swapaxes(R123, 1, 2) @ g[:, :3, :3]  # = R4 R5 R6
            for q4, q5 in _two_axes(arm.axis[3], arm.axis[4], arm.axis[5], wrist @ arm.axis[5]):
                R45 = rotation(arm.axis[3], q4) @ rotation(arm.axis[4], q5)
                across = _perpendicular(arm.axis[5])
                q6 = _turn(arm.axis[5], np.zeros(3), np.broadcast_to(across, (N, 3)),
                           np.einsum("nji,nj->ni", R45, wrist @ across))  # fmt: skip
                out[:, k] = np.stack([q1, q2, q3, q4, q5, q6], axis=1)
                k += 1
    return _wrap(out)


def _shoulder(arm: WristArm, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint 1's two angles (N,) that bring the plane joints 2 and 3 move the wrist centre in
    onto the centre's target (N, 3): in front (on the zero pose's side) and behind. Joints 2 and
    3 keep the centre's component along axis 2 (a shoulder offset, ``offset``); what is left
    in the plane of joint 1 lies along ``across`` = axis 1 x axis 2."""
    axis = arm.axis[0]
    e2 = arm.axis[1] - (arm.axis[1] @ axis) * axis
    e2 /= np.linalg.norm(e2)
    across = np.cross(axis, e2)
    zero = arm.centre - arm.point[0]
    offset, side = zero @ e2, np.sign(zero @ across) or 1.0
    u = centre - arm.point[0]
    u = u - np.outer(u @ axis, axis)
    with np.errstate(invalid="ignore"):
        along = np.sqrt(np.einsum("ni,ni->n", u, u) - offset**2)  # NaN: the centre within the offset
    out = []
    for sign in (side, -side):
        w = offset * e2 + np.outer(sign * along, across)
        out.append(np.arctan2(np.cross(w, u) @ axis, np.einsum("ni,ni->n", w, u)))
    return out[0], out[1]


def _wrap(q: np.ndarray) -> np.ndarray:
    """Angles into (-pi, pi], NaN kept."""
    return np.pi - (np.pi - q) % (2 * np.pi)


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues: rotations (N, 3, 3) about a unit axis by angles (N,)."""
    K = _skew(axis)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _turn(axis: np.ndarray, point: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Paden-Kahan 1: the angles (N,) about the axis (through ``point``) that turn points p
    (N, 3) toward q (N, 3) (exactly onto it where they lie on one circle)."""
    u, v = p - point, q - point
    u = u - np.outer(u @ axis, axis)
    v = v - np.outer(v @ axis, axis)
    return np.arctan2(np.cross(u, v) @ axis, np.einsum("ni,ni->n", u, v))


def _turns_to_distance(
    axis: np.ndarray, point: np.ndarray, p: np.ndarray, q: np.ndarray, distance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Paden-Kahan 3: the two angles (N,) about the axis that put the point p (3,) at
    ``distance`` (N,) from q (3,); NaN where no angle does."""
    u, v = p - point, q - point
    along = axis @ (p - q)
    u_plane, v_plane = u - (u @ axis) * axis, v - (v @ axis) * axis
    theta0 = np.arctan2(axis @ np.cross(u_plane, v_plane), u_plane @ v_plane)
    in_plane_sq = distance**2 - along**2
    nu, nv = np.linalg.norm(u_plane), np.linalg.norm(v_plane)
    with np.errstate(invalid="ignore"):
        cosine = (nu**2 + nv**2 - in_plane_sq) / (2.0 * nu * nv)
        half = np.arccos(np.where(np.abs(cosine) <= 1.0 + 1e-12, np.clip(cosine, -1.0, 1.0), np.nan))
    return theta0 - half, theta0 + half


def _two_axes(
    axis1: np.ndarray, axis2: np.ndarray, p: np.ndarray, q: np.ndarray
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Paden-Kahan 2 for directions: the two (theta1, theta2) (each (N,)) with
    R(axis1, theta1) R(axis2, theta2) p = q (N, 3), axes through one point; NaN where none."""
    cross = np.cross(axis1, axis2)
    dot = axis1 @ axis2
    alpha = (dot * (axis2 @ p) - q @ axis1) / (dot**2 - 1.0)
    beta = (dot * (q @ axis1) - axis2 @ p) / (dot**2 - 1.0)
    with np.errstate(invalid="ignore"):
        gamma_sq = (p @ p - alpha**2 - beta**2 - 2.0 * alpha * beta * dot) / (cross @ cross)
        gamma = np.sqrt(np.where(gamma_sq >= -1e-12, np.maximum(gamma_sq, 0.0), np.nan))
    out = []
    for sign in (1.0, -1.0):
        z = np.outer(alpha, axis1) + np.outer(beta, axis2) + np.outer(sign * gamma, cross)
        theta2 = _turn(axis2, np.zeros(3), np.broadcast_to(p, z.shape), z)
        theta1 = _turn(axis1, np.zeros(3), z, q)
        out.append((theta1, theta2))
    return out


def _perpendicular(axis: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to ``axis``."""
    other = np.eye(3)[int(np.argmin(np.abs(axis)))]
    across = np.cross(axis, other)
    return across / np.linalg.norm(across)
