"""Per-evaluation kinematics of a :class:`~fgcal.robot.Robot`: frames, gravity moments
and analytic Jacobians (SPEC sections 2 and 3).

``forward(robot, params, q)`` returns a :class:`KinematicsData`; the other functions take
the robot and that data. Nothing is stored on the robot.

Gravity moment of joint i (bodies b >= i, payload included; all forces are parallel to g,
so the sum collapses to the first mass moment ``C_i = sum m_b c_b`` and mass ``M_i``)::

    t_i = R_W_Bi^T ((C_i - M_i o_Bi) x g)       (N m, in the bending frame B_i)

evaluated on the undeformed chain. Every element's derivative is its spatial twist
``(omega, v0)``; compliances enter through ``g = k * t`` and the chain rule through t.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .ets import element_twists, evaluate

if TYPE_CHECKING:
    from .robot import Robot


@dataclass
class KinematicsData:
    """Everything computed for one parameter vector at N configurations."""

    params: np.ndarray
    q: np.ndarray
    frames: np.ndarray  # (K+1, N, 4, 4) deformed chain
    frames_rigid: np.ndarray  # (K+1, N, 4, 4) undeformed chain (g = 0)
    moments: np.ndarray  # (N, 3n) gravity moments t_i, N m
    first_moment: np.ndarray  # (N, n+2, 3) suffix sums of m_b c_b over bodies >= j, kg m
    suffix_mass: np.ndarray  # (n+2,) suffix sums of m_b, kg
    torque_world: np.ndarray  # (N, n, 3) tau_i in W, N m
    _twists: dict = field(default_factory=dict)

    def twists(self, chain_elements, rigid: bool) -> list[np.ndarray]:
        key = "rigid" if rigid else "deformed"
        if key not in self._twists:
            frames = self.frames_rigid if rigid else self.frames
            self._twists[key] = element_twists(chain_elements, self.params, frames)
        return self._twists[key]


def _body_frames(robot: Robot) -> list[int]:
    """Frame index of each body: links 1..n, then the payload (on the flange)."""
    chain = robot.chain
    return [*list(chain.link_end), chain.flange]


def _body_coms(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    masses = np.append(robot.masses, robot.payload_mass)
    coms = np.vstack([robot.coms, robot.payload_com])
    return masses, coms


def forward(robot: Robot, params: np.ndarray, q: np.ndarray) -> KinematicsData:
    """Frames and gravity moments for parameter vector ``params`` at joint angles (N, n)."""
    chain = robot.chain
    n, n_conf = robot.n_joints, q.shape[0]
    no_moments = np.zeros((n_conf, 3 * n))
    rigid = evaluate(chain.elements, params, q, no_moments)
    masses, coms = _body_coms(robot)
    body_frames = _body_frames(robot)
    # Suffix sums over bodies j..n (body n is the payload); entry n+1 is empty.
    weighted = np.stack(
        [masses[b] * (rigid[f][:, :3, :3] @ coms[b] + rigid[f][:, :3, 3]) for b, f in enumerate(body_frames)], axis=1
    )
    first_moment = np.zeros((n_conf, n + 2, 3))
    first_moment[:, :-1] = np.cumsum(weighted[:, ::-1], axis=1)[:, ::-1]
    suffix_mass = np.zeros(n + 2)
    suffix_mass[:-1] = np.cumsum(masses[::-1])[::-1]
    g = robot.gravity
    torque_world = np.empty((n_conf, n, 3))
    moments = np.empty((n_conf, 3 * n))
    for i in range(n):
        bend = rigid[chain.bend[i]]
        torque_world[:, i] = np.cross(first_moment[:, i] - suffix_mass[i] * bend[:, :3, 3], g)
        moments[:, 3 * i : 3 * i + 3] = np.einsum("nji,nj->ni", bend[:, :3, :3], torque_world[:, i])
    frames = evaluate(chain.elements, params, q, moments) if robot.model == "DH,s,e" else rigid
    return KinematicsData(params, q, frames, rigid, moments, first_moment, suffix_mass, torque_world)


def frame_index(robot: Robot, frame: str) -> int:
    chain = robot.chain
    if frame == "flange":
        return chain.flange
    if frame == "tool":
        return chain.tool
    if frame == "base":
        return chain.base_end
    raise InputError(None, "frame", f"unknown frame {frame!r} (flange, tool or base)")


def frame_pose(robot: Robot, data: KinematicsData, frame: str = "flange") -> np.ndarray:
    """Pose (N, 4, 4) of ``frame`` in W."""
    return data.frames[frame_index(robot, frame)]


def moment_derivative(robot: Robot, data: KinematicsData, element: int, twist: np.ndarray) -> np.ndarray:
    """Derivative (N, 3n) of all gravity moments w.r.t. one column of a rigid-chain element.

    ``twist`` (N, 6) is that column's spatial twist on the undeformed chain.
    """
    chain = robot.chain
    n = robot.n_joints
    omega, v0 = twist[:, :3], twist[:, 3:]
    body_frames = _body_frames(robot)
    first_body = next((b for b, f in enumerate(body_frames) if f > element), n + 1)
    g = robot.gravity
    out = np.zeros((data.q.shape[0], 3 * n))
    for i in range(n):
        start = max(i, first_body)
        moved = np.cross(omega, data.first_moment[:, start]) + data.suffix_mass[start] * v0
        bend = data.frames_rigid[chain.bend[i]]
        if element < chain.bend[i]:
            origin_rate = np.cross(omega, bend[:, :3, 3]) + v0
            d_tau = np.cross(moved - data.suffix_mass[i] * origin_rate, g) - np.cross(omega, data.torque_world[:, i])
        else:
            d_tau = np.cross(moved, g)
        out[:, 3 * i : 3 * i + 3] = np.einsum("nji,nj->ni", bend[:, :3, :3], d_tau)
    return out


def _direct_columns(robot: Robot, name: str) -> list[tuple[int, int, float | None]]:
    """Elements through which ``name`` enters directly: (element, column, joint sign or None)."""
    chain = robot.chain
    if name.startswith("q") and name[1:].isdigit():
        joint = int(name[1:]) - 1
        if not 0 <= joint < robot.n_joints:
            raise InputError(None, "wrt", f"{robot.name} has no joint {name}")
        return [(k, 0, et.sign) for k, et in enumerate(chain.elements) if et.joint == joint]
    try:
        p = robot.parameter_names.index(name)
    except ValueError:
        raise InputError(None, "wrt", f"unknown parameter or joint name {name!r}") from None
    out = []
    for k, et in enumerate(chain.elements):
        if et.axis == "Rvec" and et.param <= p < et.param + 3:
            out.append((k, p - et.param, None))
        elif et.param == p and et.axis != "Rvec":
            out.append((k, 0, None))
    return out


def spatial_jacobian(robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange") -> np.ndarray:
    """Spatial twists (N, len(wrt), 6) of ``frame`` w.r.t. each name in ``wrt``."""
    chain = robot.chain
    out_index = frame_index(robot, frame)
    twists = data.twists(chain.elements, rigid=False)
    deflections = [k for k, et in enumerate(chain.elements) if et.moment is not None and k < out_index]
    n_conf = data.q.shape[0]
    result = np.zeros((n_conf, len(wrt), 6))
    for col, name in enumerate(wrt):
        moment_rate = np.zeros((n_conf, 3 * robot.n_joints))
        for k, c, sign in _direct_columns(robot, name):
            et = chain.elements[k]
            scale = 1.0 if sign is None else sign
            if et.moment is not None:
                if k < out_index:
                    result[:, col] += twists[k][:, c] * (scale * data.moments[:, et.moment])[:, None]
                continue
            if k < out_index:
                result[:, col] += scale * twists[k][:, c]
            if deflections:
                rigid_twist = data.twists(chain.elements, rigid=True)[k][:, c]
                moment_rate += scale * moment_derivative(robot, data, k, rigid_twist)
        for k in deflections:
            et = chain.elements[k]
            compliance = data.params[et.param]
            if compliance != 0.0:
                result[:, col] += twists[k][:, 0] * (compliance * moment_rate[:, et.moment])[:, None]
    return result


def jacobian(
    robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange", point: np.ndarray | None = None
) -> np.ndarray:
    """Body twist Jacobian (N, 6, T) of ``frame``, or, with ``point`` (3,) fixed in that
    frame, the Jacobian (N, 3, T) of the point's world position. See Robot.jacobian."""
    spatial = spatial_jacobian(robot, data, wrt, frame)
    omega, v0 = spatial[..., :3], spatial[..., 3:]
    T = frame_pose(robot, data, frame)
    if point is not None:
        p_world = T[:, :3, :3] @ np.asarray(point, float) + T[:, :3, 3]
        return np.swapaxes(np.cross(omega, p_world[:, None, :]) + v0, 1, 2)
    rot_t = np.swapaxes(T[:, :3, :3], 1, 2)
    origin_velocity = np.cross(omega, T[:, None, :3, 3]) + v0
    body_omega = np.einsum("nij,ntj->nit", rot_t, omega)
    body_v = np.einsum("nij,ntj->nit", rot_t, origin_velocity)
    return np.concatenate([body_omega, body_v], axis=1)
