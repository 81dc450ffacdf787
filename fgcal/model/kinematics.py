"""Per-evaluation kinematics of a :class:`~fgcal.model.robot.Robot`: frames, gravity moments
and analytic Jacobians (SPEC sections 2 and 3).

``forward(robot, params, q, motion)`` returns a :class:`KinematicsData`; the other functions
take the robot and that data. Nothing is stored on the robot. ``motion`` are the motion-history
features of the configurations (fgcal.model.motion): with model DH,s,e,h the chain sees the joint
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
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..core.errors import InputError
from ..core.se3 import cross
from . import chain_kernel
from .ets import ROOT, Chain, ancestry, element_twists, homogeneous, layout, rvec_tables
from .parameters import MASS_KIND, is_mass, split_name


class Robot(Protocol):
    """What kinematics needs of a robot description (fgcal.model.robot.Robot provides it; this
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
    # Each frame's top three rows, (K+1, N, 3, 4): the fourth is (0, 0, 0, 1), and at
    # thousands of configurations it would be a quarter of a calibration's largest arrays.
    frames: np.ndarray  # (K+1, N, 3, 4) deformed chain
    frames_rigid: np.ndarray  # (K+1, N, 3, 4) undeformed chain (g = 0)
    moments: np.ndarray  # (N, 3L) gravity moments t_i of the L joints of the geometry, N m
    weighted: np.ndarray  # (N, B, 3) m_b c_b of each body (mass scales applied), kg m
    com_world: np.ndarray  # (N, B, 3) c_b, each body's centre of mass in W, m
    carried_mass: np.ndarray  # (L,) M_i: the mass joint i carries, kg
    body_masses: np.ndarray  # (B,) m_b, mass scales applied, kg
    torque_world: np.ndarray  # (N, L, 3) tau_i in W, N m
    rvec_left: np.ndarray  # (R, 3, 3) left Jacobians of the rotation-vector elements (ets.rvec_tables)
    motion: np.ndarray | None = None  # (N, 2n) motion-history features (fgcal.model.motion)

    def subset(self, rows: np.ndarray) -> KinematicsData:
        """The data of some of the configurations (what forward() would give for them)."""
        return KinematicsData(
            self.params, self.q[rows], self.frames[:, rows], self.frames_rigid[:, rows], self.moments[rows],
            self.weighted[rows], self.com_world[rows], self.carried_mass, self.body_masses, self.torque_world[rows],
            self.rvec_left, None if self.motion is None else self.motion[rows],
        )  # fmt: skip


def _body_frames(robot: Robot) -> list[int]:
    """Frame index of each body: links 1..n, then the payload (on the flange)."""
    chain = robot.chain
    return [*list(chain.link_end), chain.flange]


_BODY_COMS: dict[int, tuple[Robot, np.ndarray, np.ndarray]] = {}


def _body_coms(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """Each body's mass (B,) and centre of mass (B, 3) in its frame: the links, then the payload.
    Cached on the (frozen) robot's identity, as the chain's tables are."""
    entry = _BODY_COMS.get(id(robot))
    if entry is None or entry[0] is not robot:
        if len(_BODY_COMS) > 256:
            _BODY_COMS.clear()
        masses = np.append(robot.masses, robot.payload_mass).astype(float)
        coms = np.ascontiguousarray(np.vstack([robot.coms, robot.payload_com]), dtype=float)
        masses.flags.writeable = coms.flags.writeable = False
        entry = _BODY_COMS[id(robot)] = (robot, masses, coms)
    return entry[1], entry[2]


@dataclass(frozen=True)
class _Bodies:
    """What moves what, per chain: ``carried`` (n, B) bool, joint i carries body b (its motion,
    the element ending at B_i, moves it); element k moves the bodies ``set_bodies[moved_set[k]]``
    (S, B: the distinct sets);
    ``moves_bend`` (n, K) those that move each bending frame; ``body_frame`` (B,) and ``bend``
    (n,) the frames of the bodies and of the bending frames."""

    carried: np.ndarray
    moved_set: np.ndarray
    set_bodies: np.ndarray
    moves_bend: np.ndarray
    body_frame: np.ndarray
    bend: np.ndarray


_BODIES: dict[int, tuple[Chain, _Bodies]] = {}


def _bodies(robot: Robot) -> _Bodies:
    # Cached on the chain's identity (the entry keeps it alive): a single configuration's
    # evaluation costs microseconds, which rebuilding these masks would add to.
    chain = robot.chain
    entry = _BODIES.get(id(chain))
    if entry is None or entry[0] is not chain:
        if len(_BODIES) > 256:
            _BODIES.clear()
        paths = ancestry(chain.elements)
        body_frame = np.array(_body_frames(robot), dtype=np.int64)
        moved = paths[body_frame]
        bend = np.array(chain.bend, dtype=np.int64)
        set_bodies, moved_set = np.unique(moved.T, axis=0, return_inverse=True)
        bodies = _Bodies(
            np.ascontiguousarray(moved[:, bend - 1].T), moved_set.reshape(-1).astype(np.int64),
            np.ascontiguousarray(set_bodies), paths[bend], body_frame, bend,
        )  # fmt: skip
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
    """The joint offsets (N, n) of the motion history (fgcal.model.motion), rad or m."""
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
    n, n_conf = robot.n_links, q.shape[0]
    chain = robot.chain.elements
    chain_layout = layout(chain)
    params, q = np.ascontiguousarray(params, dtype=float), np.ascontiguousarray(q, dtype=float)
    moments = np.empty((n_conf, 3 * n))
    chain_layout.check(params, q, moments)
    masses, coms = _body_coms(robot)
    if robot.mass_groups:  # else the scales are all 1: the cached (read-only) masses serve
        masses = masses * body_scales(robot, params)
    bodies = _bodies(robot)
    rigid = np.empty((len(chain) + 1, n_conf, 3, 4))
    frames = np.empty_like(rigid) if robot.compliant else rigid
    com_world, weighted = np.empty((n_conf, len(masses), 3)), np.empty((n_conf, len(masses), 3))
    torque_world, carried_mass = np.empty((n_conf, n, 3)), np.empty(n)
    rotations, left = rvec_tables(chain, params)
    chain_kernel.forward(
        chain_layout.tables, chain_layout.constants, rotations, params, q, ROOT,
        bodies.body_frame, coms, masses, bodies.carried, bodies.bend, np.asarray(robot.gravity, dtype=float),
        robot.compliant, rigid, frames, com_world, weighted, torque_world, moments, carried_mass,
    )  # fmt: skip
    return KinematicsData(
        params, q, frames, rigid, moments, weighted, com_world, carried_mass, masses, torque_world, left, motion
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
    return homogeneous(data.frames[frame_index(robot, frame)])


_ENTRIES: dict[tuple[int, tuple[str, ...]], tuple] = {}


def _entry_arrays(robot: Robot, wrt: Sequence[str]) -> tuple[list, np.ndarray, np.ndarray, tuple]:
    """_direct_columns' entries; as the kernel takes them, their (5, E) targets, elements,
    columns, features and the moment of each element (-1: none), and their scales (E,); and the
    mass scales among the names (position, name). Cached per chain and names, since an IK or an
    online update asks for the same columns at every evaluation."""
    chain, key = robot.chain, tuple(wrt)
    entry = _ENTRIES.get((id(chain), key))
    if entry is None or entry[0] is not chain:
        if len(_ENTRIES) > 256:
            _ENTRIES.clear()
        entries = _direct_columns(robot, wrt)
        targets, elements, columns, scales, features = (
            np.array(v) for v in (zip(*entries, strict=True) if entries else [()] * 5)
        )
        moments = [-1 if chain.elements[k].moment is None else chain.elements[k].moment for k in elements]
        packed = np.array([targets, elements, columns, features, moments], dtype=np.int64).reshape(5, -1)
        scales = np.asarray(scales, dtype=float)
        packed.flags.writeable = scales.flags.writeable = False  # shared by every later evaluation
        masses = tuple((t, name) for t, name in enumerate(wrt) if is_mass(name))
        entry = _ENTRIES[(id(chain), key)] = (chain, entries, packed, scales, masses)
    return entry[1:]


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


@dataclass(frozen=True)
class _Path:
    """What moves a frame: ``moves`` (K,) the elements on its path, and the deflections among
    them (element, its parameter, its moment)."""

    moves: np.ndarray
    deflections: np.ndarray
    deflection_param: np.ndarray
    deflection_moment: np.ndarray
    packed: np.ndarray  # (2, M) deflections and deflection_moment as one array (their memory), for the kernel


_PATHS: dict[tuple[int, int], tuple[Chain, _Path]] = {}


def _path(robot: Robot, out_index: int) -> _Path:
    chain = robot.chain
    entry = _PATHS.get((id(chain), out_index))
    if entry is None or entry[0] is not chain:
        if len(_PATHS) > 256:
            _PATHS.clear()
        moves = ancestry(chain.elements)[out_index]
        deflections = [k for k, et in enumerate(chain.elements) if et.moment is not None and moves[k]]

        def array(values: list) -> np.ndarray:
            return np.array(values, dtype=np.int64).reshape(-1)

        packed = np.array([deflections, [chain.elements[k].moment for k in deflections]], dtype=np.int64).reshape(2, -1)
        path = _Path(moves, packed[0], array([chain.elements[k].param for k in deflections]), packed[1], packed)
        entry = _PATHS[(id(chain), out_index)] = (chain, path)
    return entry[1]


_NO_MOTION = np.zeros((1, 0))


def spatial_jacobian(robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange") -> np.ndarray:
    """Spatial twists (N, len(wrt), 6) of ``frame`` w.r.t. each name in ``wrt``.

    Each name enters through its elements' twists on the deformed chain (a compliance times its
    gravity moment, a motion term times its motion feature). A geometric parameter or a joint
    also changes the gravity moments of the undeformed chain, which bend every deflection on
    the frame's path: for the bodies S that joint i carries and the column (omega, v0) moves::

        d tau_i = ((omega x C_S + M_S v0) - [upstream of B_i] M_i (omega x o_i + v0)) x g
        d t_i   = R_i^T (d tau_i - [upstream of B_i] omega x tau_i)
    """
    chain = robot.chain
    path = _path(robot, frame_index(robot, frame))
    entries, packed, scales, masses = _entry_arrays(robot, wrt)
    out = np.zeros((data.q.shape[0], len(wrt), 6))
    if entries:
        chain_layout = layout(chain.elements)
        bodies = _bodies(robot)
        chain_kernel.spatial_columns(
            chain_layout.tables, data.rvec_left, data.frames, data.frames_rigid, packed, scales, path.moves,
            _NO_MOTION if data.motion is None else data.motion, data.moments,
            path.packed, data.params[path.deflection_param],
            bodies.carried, bodies.moved_set, bodies.set_bodies, bodies.moves_bend, bodies.bend, data.weighted,
            data.body_masses, data.carried_mass, data.torque_world, np.asarray(robot.gravity, dtype=float), out,
        )  # fmt: skip
    if masses:
        _add_mass_columns(robot, data, masses, path, out)
    return out


def _add_mass_columns(robot: Robot, data: KinematicsData, names: tuple, path: _Path, out: np.ndarray) -> None:
    """Add to ``out`` (N, T, 6) the twists of the mass scales ``names`` ((position, name)): a group's mass scale
    mu_g changes the gravity moments, ``d t_i / d mu_g = R_i^T sum_b m_b (c_b - o_i) x g`` over
    the group's bodies b that joint i carries, and the moments bend the deflections."""
    if not path.deflections.size:
        return
    chain = robot.chain
    compliances = data.params[path.deflection_param]
    if not np.any(compliances != 0.0):
        return
    deflection_twists = element_twists(
        chain.elements, data.params, data.frames, path.deflections, np.zeros_like(path.deflections)
    )  # (N, M, 6)
    masses, _ = _body_coms(robot)
    carried = carries(robot)
    bends = data.frames_rigid[list(chain.bend)]  # (L, N, 3, 4)
    origins = np.swapaxes(bends[:, :, :3, 3], 0, 1)  # (N, L, 3)
    rotations = np.swapaxes(bends[:, :, :3, :3], 0, 1)  # (N, L, 3, 3)
    groups = dict(robot.mass_groups)
    for t, name in names:
        in_group = np.zeros(len(masses), dtype=bool)
        in_group[list(groups[split_name(name)[1]])] = True
        A = carried * (in_group * masses)[None, :]  # (L, B)
        lever = np.matmul(A, data.com_world) - A.sum(axis=1)[None, :, None] * origins
        rate = np.matmul(cross(lever, robot.gravity)[:, :, None, :], rotations)[:, :, 0, :]  # (N, L, 3)
        rates = rate.reshape(rate.shape[0], -1)[:, path.deflection_moment] * compliances  # (N, M)
        out[:, t] += np.einsum("nm,nmk->nk", rates, deflection_twists)


def jacobian(
    robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange", point: np.ndarray | None = None
) -> np.ndarray:
    """Body twist Jacobian (N, 6, T) of ``frame``, or, with ``point`` (3,) fixed in that
    frame, the Jacobian (N, 3, T) of the point's world position. See Robot.jacobian."""
    if point is not None:
        point = np.asarray(point, dtype=float)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise InputError(None, "point", f"a finite point (3,) in the frame, m; got shape {point.shape}")
    spatial = spatial_jacobian(robot, data, wrt, frame)
    pose = data.frames[frame_index(robot, frame)]  # (N, 3, 4): the kernels read no fourth row
    if point is not None:
        out = np.empty((spatial.shape[0], 3, spatial.shape[1]))
        chain_kernel.point_rates(spatial, pose, point, out)
    else:
        # In the spatial twists' own memory: at thousands of configurations and a full model,
        # a second array of this size would add to the peak of a calibration.
        out = spatial.reshape(spatial.shape[0], 6, spatial.shape[1])
        chain_kernel.body_twists(spatial, pose, out)
    return out
