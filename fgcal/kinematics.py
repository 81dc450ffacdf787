"""Per-evaluation kinematics of a :class:`~fgcal.robot.Robot`: frames, gravity moments
and analytic Jacobians (SPEC sections 2 and 3).

``forward(robot, params, q, motion)`` returns a :class:`KinematicsData`; the other functions
take the robot and that data. Nothing is stored on the robot. ``motion`` are the motion-history
features of the configurations (fgcal.motion): with model DH,s,e,h the chain sees the joint
values ``q' = q + F_lm lm + F_lv lv`` (N, n), and every derivative goes through q'.

Gravity moment of joint i (the bodies it carries: those its motion moves, payload included;
on a serial chain, b >= i; on a tree, every branch beyond it; all forces are parallel to g, so
the sum collapses to the first mass moment ``C_i = sum m_b c_b`` and mass ``M_i``)::

    t_i = R_W_Bi^T ((C_i - M_i o_Bi) x g)       (N m, in the bending frame B_i)

evaluated on the undeformed chain. Every element's derivative is its spatial twist
``(omega, v0)``; compliances enter through ``g = k * t`` and the chain rule through t.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .errors import InputError
from .ets import Chain, ancestry, element_twists, evaluate
from .parameters import MASS_KIND, is_mass, split_name
from .se3 import cross


class Robot(Protocol):
    """What kinematics needs of a robot description (fgcal.robot.Robot provides it; this
    module does not import it, so that the description can call kinematics)."""

    name: str
    model: str
    masses: np.ndarray
    compliant: bool
    history: bool
    coms: np.ndarray
    payload_mass: float
    payload_com: np.ndarray
    gravity: np.ndarray

    @property
    def chain(self) -> Chain: ...

    @property
    def n_joints(self) -> int: ...

    @property
    def n_links(self) -> int: ...

    mass_groups: tuple[tuple[str, tuple[int, ...]], ...]

    @property
    def parameter_names(self) -> list[str]: ...


@dataclass
class KinematicsData:
    """Everything computed for one parameter vector at N configurations."""

    params: np.ndarray
    q: np.ndarray  # (N, n) the joint values the chain sees: commanded plus motion offsets
    frames: np.ndarray  # (K+1, N, 4, 4) deformed chain
    frames_rigid: np.ndarray  # (K+1, N, 4, 4) undeformed chain (g = 0)
    moments: np.ndarray  # (N, 3L) gravity moments t_i of the L joints of the geometry, N m
    weighted: np.ndarray  # (N, B, 3) m_b c_b of each body (mass scales applied), kg m
    com_world: np.ndarray  # (N, B, 3) c_b, each body's centre of mass in W, m
    carried_mass: np.ndarray  # (L,) M_i: the mass joint i carries, kg
    body_masses: np.ndarray  # (B,) m_b, mass scales applied, kg
    torque_world: np.ndarray  # (N, L, 3) tau_i in W, N m
    motion: np.ndarray | None = None  # (N, 2n) motion-history features (fgcal.motion)
    _twists: dict = field(default_factory=dict)

    def subset(self, rows: np.ndarray) -> KinematicsData:
        """The data of some of the configurations (what forward() would give for them)."""
        return KinematicsData(
            self.params, self.q[rows], self.frames[:, rows], self.frames_rigid[:, rows], self.moments[rows],
            self.weighted[rows], self.com_world[rows], self.carried_mass, self.body_masses, self.torque_world[rows],
            None if self.motion is None else self.motion[rows],
        )  # fmt: skip

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


@dataclass(frozen=True)
class _Bodies:
    """What moves what, per chain: ``carried`` (n, B) bool, joint i carries body b (its motion,
    the element ending at B_i, moves it); ``moved`` (B, K) the elements that move each body;
    ``moves_bend`` (n, K) those that move each bending frame."""

    carried: np.ndarray
    moved: np.ndarray
    moves_bend: np.ndarray


_BODIES: dict[int, tuple[Chain, _Bodies]] = {}


def _bodies(robot: Robot) -> _Bodies:
    # Cached on the chain's identity (the entry keeps it alive): a single configuration's
    # evaluation costs tens of microseconds, which rebuilding these masks would add to.
    chain = robot.chain
    entry = _BODIES.get(id(chain))
    if entry is None or entry[0] is not chain:
        if len(_BODIES) > 256:
            _BODIES.clear()
        paths = ancestry(chain.elements)
        moved = paths[_body_frames(robot)]
        bodies = _Bodies(moved[:, [b - 1 for b in chain.bend]].T, moved, paths[list(chain.bend)])
        entry = _BODIES[id(chain)] = (chain, bodies)
    return entry[1]


def carries(robot: Robot) -> np.ndarray:
    """(n, B) bool: joint i carries body b (its motion, the element ending at B_i, moves it)."""
    return _bodies(robot).carried


def path_parameters(robot: Robot, frame: str | int) -> set[str]:
    """The parameters of the elements on the path from the root to ``frame`` (a tip's chain:
    what moves it geometrically; a mass scale, which moves it only through the moments, is not
    among them) and the motion terms of the joints on that path."""
    chain = robot.chain
    on_path = ancestry(chain.elements)[frame_index(robot, frame)]
    names = robot.parameter_names
    out = set()
    for k, et in enumerate(chain.elements):
        if not on_path[k]:
            continue
        if et.param is not None:
            out.update(names[et.param : et.param + (3 if et.axis == "Rvec" else 1)])
        if et.joint is not None and robot.history:
            out.update({f"lm{et.joint + 1}", f"lv{et.joint + 1}"})
    return out


def path_joints(robot: Robot, frame: str | int) -> np.ndarray:
    """(n,) bool: the joints the controller moves whose motion lies on ``frame``'s path (all of
    a serial chain's, for its flange or tool)."""
    chain = robot.chain
    on_path = ancestry(chain.elements)[frame_index(robot, frame)]
    out = np.zeros(robot.n_joints, dtype=bool)
    for k, et in enumerate(chain.elements):
        if et.joint is not None and on_path[k]:
            out[et.joint] = True
    return out


def motion_offsets(robot: Robot, params: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """The joint offsets (N, n) of the motion history (fgcal.motion), rad or m."""
    first = robot.parameter_names.index("lm1")
    n = robot.n_joints
    return motion[:, :n] * params[first : first + n] + motion[:, n:] * params[first + n : first + 2 * n]


def forward(robot: Robot, params: np.ndarray, q: np.ndarray, motion: np.ndarray | None = None) -> KinematicsData:
    """Frames and gravity moments for parameter vector ``params`` at joint values (N, n),
    reached as the motion-history features (N, 2n) say (None: no history offsets)."""
    if motion is not None and not robot.history:
        motion = None
    if motion is not None:
        motion = np.asarray(motion, dtype=float)
        if motion.shape != (q.shape[0], 2 * robot.n_joints):
            raise ValueError(f"motion features of shape {motion.shape} for joint values of shape {q.shape}")
        q = q + motion_offsets(robot, params, motion)
    chain = robot.chain
    n, n_conf = robot.n_links, q.shape[0]
    no_moments = np.zeros((n_conf, 3 * n))
    rigid = evaluate(chain.elements, params, q, no_moments)
    masses, coms = _body_coms(robot)
    scale = body_scales(robot, params)
    masses = masses * scale
    body_frames = _body_frames(robot)
    com_world = np.stack(
        [rigid[f][:, :3, :3] @ coms[b] + rigid[f][:, :3, 3] for b, f in enumerate(body_frames)], axis=1
    )
    weighted = masses[None, :, None] * com_world
    carried = carries(robot).astype(float)  # (n, B)
    first_moment = np.matmul(carried, weighted)  # (N, n, 3): C_i
    carried_mass = carried @ masses
    g = robot.gravity
    torque_world = np.empty((n_conf, n, 3))
    moments = np.empty((n_conf, 3 * n))
    for i in range(n):
        bend = rigid[chain.bend[i]]
        torque_world[:, i] = cross(first_moment[:, i] - carried_mass[i] * bend[:, :3, 3], g)
        moments[:, 3 * i : 3 * i + 3] = np.einsum("nji,nj->ni", bend[:, :3, :3], torque_world[:, i])
    frames = evaluate(chain.elements, params, q, moments) if robot.compliant else rigid
    return KinematicsData(
        params, q, frames, rigid, moments, weighted, com_world, carried_mass, masses, torque_world, motion
    )


def body_scales(robot: Robot, params: np.ndarray) -> np.ndarray:
    """(B,) each body's mass scale: its group's mass.{group} parameter, 1 outside the groups
    (the payload's mass is the robot file's)."""
    scale = np.ones(robot.n_links + 1)
    for group, members in robot.mass_groups:
        scale[list(members)] = params[robot.parameter_names.index(f"{MASS_KIND}.{group}")]
    return scale


def frame_index(robot: Robot, frame: str | int) -> int:
    """The index in the frames of ``frame``: flange, tool, base, or an index itself (a tree's
    tip, any frame of the chain)."""
    chain = robot.chain
    if isinstance(frame, (int, np.integer)) and not isinstance(frame, bool):
        if not 0 <= frame <= len(chain.elements):
            raise InputError(None, "frame", f"no frame {frame} in a chain of {len(chain.elements)} elements")
        return int(frame)
    if frame == "flange":
        return chain.flange
    if frame == "tool":
        return chain.tool
    if frame == "base":
        return chain.base_end
    named = dict(chain.tips)
    if frame in named:
        return named[frame]
    tips = f", or a tip: {', '.join(named)}" if len(named) > 1 else ""
    raise InputError(None, "frame", f"unknown frame {frame!r} (flange, tool or base{tips})")


def frame_pose(robot: Robot, data: KinematicsData, frame: str = "flange") -> np.ndarray:
    """Pose (N, 4, 4) of ``frame`` in W."""
    return data.frames[frame_index(robot, frame)]


def moment_derivatives(robot: Robot, data: KinematicsData, elements: np.ndarray, twists: np.ndarray) -> np.ndarray:
    """Derivatives (N, E, 3n) of all gravity moments w.r.t. E columns of rigid-chain elements.

    ``elements`` (E,) are the element indices, ``twists`` (N, E, 6) the columns' spatial
    twists on the undeformed chain. For the bodies S that joint i carries and the column moves::

        d tau_i = ((omega x C_S + M_S v0) - [upstream of B_i] M_i (omega x o_i + v0)) x g
        d t_i   = R_i^T (d tau_i - [upstream of B_i] omega x tau_i)
    """
    chain = robot.chain
    n = robot.n_links
    bodies = _bodies(robot)
    masses = data.body_masses
    # S: bodies joint i carries that the column moves (on a serial chain, those beyond both).
    moved_bodies = bodies.moved[:, elements].T  # (E, B)
    S = (bodies.carried[None, :, :] & moved_bodies[:, None, :]).astype(float)  # (E, n, B)
    upstream = bodies.moves_bend[:, elements].T[None, :, :, None]  # (1, E, n, 1): the column moves B_i
    omega, v0 = twists[..., None, :3], twists[..., None, 3:]  # (N, E, 1, 3)
    E = len(elements)
    first_moment = np.matmul(S.reshape(E * n, -1), data.weighted).reshape(-1, E, n, 3)  # (N, E, n, 3)
    moved = cross(omega, first_moment) + (S @ masses)[None, :, :, None] * v0
    bends = data.frames_rigid[list(chain.bend)]  # (n, N, 4, 4)
    origins = np.swapaxes(bends[:, :, :3, 3], 0, 1)[:, None]  # (N, 1, n, 3)
    rotations = np.swapaxes(bends[:, :, :3, :3], 0, 1)  # (N, n, 3, 3)
    origin_rate = cross(omega, origins) + v0
    g = robot.gravity
    lever = moved - np.where(upstream, data.carried_mass[None, None, :, None] * origin_rate, 0.0)
    d_tau = cross(lever, g) - np.where(upstream, cross(omega, data.torque_world[:, None]), 0.0)
    # (R_i^T d)^T = d^T R_i, as one batched matmul.
    d_t = np.matmul(d_tau[..., None, :], rotations[:, None])[..., 0, :]
    return d_t.reshape(d_t.shape[0], d_t.shape[1], 3 * n)


MOMENT_BLOCK_VALUES = 1_000_000  # floats in one of moment_derivatives' temporaries (8 MB)


_ENTRIES: dict[tuple[int, tuple[str, ...]], tuple] = {}


def _entry_arrays(robot: Robot, wrt: Sequence[str]) -> tuple[list, tuple[np.ndarray, ...]]:
    """_direct_columns' entries and, as arrays, their targets, elements, columns, scales,
    features and the moment of each element (-1: none): cached per chain and names, since an
    IK or an online update asks for the same columns at every evaluation."""
    chain, key = robot.chain, tuple(wrt)
    entry = _ENTRIES.get((id(chain), key))
    if entry is None or entry[0] is not chain:
        if len(_ENTRIES) > 256:
            _ENTRIES.clear()
        entries = _direct_columns(robot, wrt)
        arrays = tuple(np.array(v) for v in zip(*entries, strict=True)) if entries else (np.zeros(0, int),) * 5
        moments = np.array([-1 if chain.elements[k].moment is None else chain.elements[k].moment for k in arrays[1]])
        arrays = (*arrays, moments.astype(int))
        for array in arrays:
            array.flags.writeable = False  # shared by every later evaluation
        entry = _ENTRIES[(id(chain), key)] = (chain, entries, arrays)
    return entry[1], entry[2]


def _direct_columns(robot: Robot, wrt: Sequence[str]) -> list[tuple[int, int, int, float, int]]:
    """Entries (target, element, column, scale, feature) through which each name enters
    directly; ``feature`` >= 0: a motion term, which enters through its joint scaled by that
    column of the motion features (-1: none)."""
    chain = robot.chain
    index = {name: t for t, name in enumerate(robot.parameter_names)}
    by_param: dict[int, list[tuple[int, int]]] = {}
    by_joint: dict[int, list[tuple[int, float]]] = {}
    for k, et in enumerate(chain.elements):
        if et.axis == "Rvec":
            for c in range(3):
                by_param.setdefault(et.param + c, []).append((k, c))
        elif et.param is not None:
            by_param.setdefault(et.param, []).append((k, 0))
        if et.joint is not None:
            by_joint.setdefault(et.joint, []).append((k, et.sign))
    n = robot.n_joints
    first_motion = index.get("lm1", -1)  # a chain without motion terms has no such names
    entries = []
    for t, name in enumerate(wrt):
        if name.startswith("q") and name[1:].isdigit():
            joint = int(name[1:]) - 1
            if not 0 <= joint < n:
                raise InputError(None, "wrt", f"{robot.name} has no joint {name}")
            entries += [(t, k, 0, sign, -1) for k, sign in by_joint.get(joint, [])]
        elif name in index and 0 <= first_motion <= index[name] < first_motion + 2 * n:
            feature = index[name] - first_motion
            entries += [(t, k, 0, sign, feature) for k, sign in by_joint.get(feature % n, [])]
        elif name in index:
            entries += [(t, k, c, 1.0, -1) for k, c in by_param.get(index[name], [])]
        else:
            raise InputError(None, "wrt", f"unknown parameter or joint name {name!r}")
    return entries


def spatial_jacobian(robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange") -> np.ndarray:
    """Spatial twists (N, len(wrt), 6) of ``frame`` w.r.t. each name in ``wrt``."""
    chain = robot.chain
    out_index = frame_index(robot, frame)
    n_conf = data.q.shape[0]
    entries, (targets, elements, columns, scales, features, moment_of) = _entry_arrays(robot, wrt)
    moves_out = ancestry(chain.elements)[out_index]  # (K,) the elements on the frame's path
    deflections = [k for k, et in enumerate(chain.elements) if et.moment is not None and moves_out[k]]
    if not entries:
        out = np.zeros((n_conf, len(wrt), 6))
        _add_mass_columns(robot, data, wrt, deflections, out)
        return out
    deformed = data.twists(chain.elements, rigid=False)
    twist = np.stack([deformed[k][:, c] for k, c in zip(elements, columns, strict=True)], axis=1)  # (N, E, 6)
    is_compliance = moment_of >= 0
    # Each entry's factor per configuration: its scale, times its motion feature if it has one
    # (with no history given, a motion term moves nothing).
    scale = np.broadcast_to(scales, (n_conf, len(entries))).copy()
    motion_entries = features >= 0
    if np.any(motion_entries):
        scale[:, motion_entries] *= 0.0 if data.motion is None else data.motion[:, features[motion_entries]]
    coefficient = scale.copy()
    coefficient[:, is_compliance] *= data.moments[:, moment_of[is_compliance]]
    coefficient[:, ~moves_out[elements]] = 0.0
    contribution = twist * coefficient[..., None]

    geometric = ~is_compliance
    if deflections and np.any(geometric):
        compliances = np.array([data.params[chain.elements[k].param] for k in deflections])
        moment_index = [chain.elements[k].moment for k in deflections]
        if np.any(compliances != 0.0):
            rigid = data.twists(chain.elements, rigid=True)
            deflection_twists = np.stack([deformed[k][:, 0] for k in deflections], axis=1)  # (N, M, 6)
            # In blocks of columns: the moments' derivatives hold (N, columns, L, 3) temporaries,
            # hundreds of MB for thousands of configurations at once.
            where = np.flatnonzero(geometric)
            block = max(1, MOMENT_BLOCK_VALUES // (n_conf * 3 * robot.n_links))
            for start in range(0, len(where), block):
                some = where[start : start + block]
                rigid_twist = np.stack([rigid[k][:, c] for k, c in zip(elements[some], columns[some], strict=True)], 1)
                rates = moment_derivatives(robot, data, elements[some], rigid_twist)[:, :, moment_index]
                weighted = rates * (compliances[None, None, :] * scale[:, some][:, :, None])
                contribution[:, some] += np.matmul(weighted, deflection_twists)
    # Sum the entries into their targets (a name may enter through several elements).
    selection = np.zeros((len(wrt), len(entries)))
    selection[targets, np.arange(len(entries))] = 1.0
    out = np.matmul(selection, contribution)
    _add_mass_columns(robot, data, wrt, deflections, out)
    return out


def _add_mass_columns(robot: Robot, data: KinematicsData, wrt: Sequence[str], deflections: list[int], out) -> None:
    """Add to ``out`` (N, T, 6) the twists of the mass scales in ``wrt``: a group's mass scale
    mu_g changes the gravity moments, ``d t_i / d mu_g = R_i^T sum_b m_b (c_b - o_i) x g`` over
    the group's bodies b that joint i carries, and the moments bend the deflections."""
    names = [(t, name) for t, name in enumerate(wrt) if is_mass(name)]
    if not names or not deflections:
        return
    chain = robot.chain
    compliances = np.array([data.params[chain.elements[k].param] for k in deflections])
    if not np.any(compliances != 0.0):
        return
    moment_index = [chain.elements[k].moment for k in deflections]
    deformed = data.twists(chain.elements, rigid=False)
    deflection_twists = np.stack([deformed[k][:, 0] for k in deflections], axis=1)  # (N, M, 6)
    masses, _ = _body_coms(robot)
    carried = carries(robot)
    bends = data.frames_rigid[list(chain.bend)]  # (L, N, 4, 4)
    origins = np.swapaxes(bends[:, :, :3, 3], 0, 1)  # (N, L, 3)
    rotations = np.swapaxes(bends[:, :, :3, :3], 0, 1)  # (N, L, 3, 3)
    groups = dict(robot.mass_groups)
    for t, name in names:
        in_group = np.zeros(len(masses), dtype=bool)
        in_group[list(groups[split_name(name)[1]])] = True
        A = carried * (in_group * masses)[None, :]  # (L, B)
        lever = np.matmul(A, data.com_world) - A.sum(axis=1)[None, :, None] * origins
        rate = np.matmul(cross(lever, robot.gravity)[:, :, None, :], rotations)[:, :, 0, :]  # (N, L, 3)
        rates = rate.reshape(rate.shape[0], -1)[:, moment_index] * compliances  # (N, M)
        out[:, t] += np.einsum("nm,nmk->nk", rates, deflection_twists)


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
        return np.swapaxes(cross(omega, p_world[:, None, :]) + v0, 1, 2)
    origin_velocity = cross(omega, T[:, None, :3, 3]) + v0
    # One batched matmul (einsum is several times slower on these shapes).
    stacked = np.concatenate([omega, origin_velocity], axis=1)  # (N, 2T, 3)
    body = np.matmul(stacked, T[:, :3, :3])  # rows: (R^T w)^T = w^T R
    n_wrt = omega.shape[1]
    return np.concatenate([np.swapaxes(body[:, :n_wrt], 1, 2), np.swapaxes(body[:, n_wrt:], 1, 2)], axis=1)
