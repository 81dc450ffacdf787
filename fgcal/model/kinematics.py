"""Per-evaluation kinematics of a :class:`~fgcal.model.robot.Robot`: frames, gravity moments
and analytic Jacobians (SPEC sections 2 and 3).

``forward(robot, params, q, motion)`` returns a :class:`KinematicsData`; the other functions
take the robot and that data. For one configuration at a time, :func:`forward_jacobian` fills a
:class:`Workspace` its caller made once (Pinocchio's Data): FK and one Jacobian in one compiled
call. The robot's constant tables are its compiled model
(fgcal.model.chain_model, built once per robot); nothing is kept between calls. ``motion`` are
the motion-history features of the configurations (fgcal.model.motion): with model DH,s,e,h the
chain sees the joint values ``q' = q + F_lm lm + F_lv lv`` (N, n), and every derivative goes
through q'.

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
from functools import cached_property
from typing import Protocol

import numpy as np

from ..core.errors import InputError
from . import chain_kernel, chain_model, jacobian_kernel
from .chain_model import ChainModel, Description
from .ets import homogeneous


class Robot(Description, Protocol):
    """What kinematics needs of a robot description: what its compiled model is built from
    (fgcal.model.chain_model.Description), its model's name and its number of links.
    fgcal.model.robot.Robot provides it, and its compiled model as ``compiled``; this module does
    not import it, so that the description can call kinematics."""

    model: str

    @property
    def n_links(self) -> int: ...


# The arrays of an evaluation that do not grow with the configurations.
_CONSTANT_OVER_CONFIGURATIONS = ("carried_mass", "body_masses", "rvec_left")


@dataclass(eq=False)
class KinematicsData:
    """Everything computed for one parameter vector at N configurations: Pinocchio's Data to
    the robot's compiled model (``model``). The compiled kernels fill and read one ``buffer``
    whole (one array argument where there would be nine); the arrays below are made from it when
    first read. The frames are views; the gravity arrays (moments to rvec_left) read-only
    copies, a few per cent of the buffer: a caller that keeps the moments (the identifiability
    analysis, after the graph's evaluations are forgotten) must not keep the frames' tens of
    megabytes alive with them. (Not frozen: a frozen dataclass's construction costs 0.4 us more,
    a tenth of a single configuration's FK.)"""

    model: ChainModel
    params: np.ndarray
    q: np.ndarray  # (N, n) the joint values the chain sees: commanded plus motion offsets
    buffer: np.ndarray  # every array below (chain_kernel.evaluation)
    motion: np.ndarray | None = None  # (N, 2n) motion-history features (fgcal.model.motion)

    # Each frame's top three rows, (K+1, N, 3, 4): the fourth is (0, 0, 0, 1), and at
    # thousands of configurations it would be a quarter of a calibration's largest arrays.
    @cached_property
    def frames(self) -> np.ndarray:
        """(K+1, N, 3, 4) the deformed chain (the undeformed one's memory for a rigid model)."""
        return self._array("frames")

    @cached_property
    def frames_rigid(self) -> np.ndarray:
        """(K+1, N, 3, 4) the undeformed chain (g = 0)."""
        return self._array("frames_rigid")

    @cached_property
    def moments(self) -> np.ndarray:
        """(N, 3L) gravity moments t_i of the L joints of the geometry, N m."""
        return self._copy("moments")

    @cached_property
    def weighted(self) -> np.ndarray:
        """(N, B, 3) m_b c_b of each body (mass scales applied), kg m."""
        return self._copy("weighted")

    @cached_property
    def com_world(self) -> np.ndarray:
        """(N, B, 3) c_b, each body's centre of mass in W, m."""
        return self._copy("com_world")

    @cached_property
    def carried_mass(self) -> np.ndarray:
        """(L,) M_i: the mass joint i carries, kg."""
        return self._copy("carried_mass")

    @cached_property
    def body_masses(self) -> np.ndarray:
        """(B,) m_b, mass scales applied, kg."""
        return self._copy("body_masses")

    @cached_property
    def torque_world(self) -> np.ndarray:
        """(N, L, 3) tau_i in W, N m."""
        return self._copy("torque_world")

    @cached_property
    def rvec_left(self) -> np.ndarray:
        """(R, 3, 3) left Jacobians of the rotation-vector elements."""
        return self._copy("rvec_left")

    def _array(self, name: str) -> np.ndarray:
        return self.model.array(self.buffer, name, len(self.q))

    def _copy(self, name: str) -> np.ndarray:
        out = self._array(name).copy()
        out.flags.writeable = False
        return out

    def subset(self, rows: np.ndarray) -> KinematicsData:
        """The data of some of the configurations (what forward() would give for them)."""
        q = self.q[rows]
        out = KinematicsData(
            self.model, self.params, q, np.empty(self.model.buffer_size(len(q))),
            None if self.motion is None else self.motion[rows],
        )  # fmt: skip
        for name in chain_model.EVALUATION:
            part = self._array(name)
            if name.startswith("frames"):
                part = part[:, rows]
            elif name not in _CONSTANT_OVER_CONFIGURATIONS:
                part = part[rows]
            out._array(name)[...] = part
        return out


def carries(robot: Robot) -> np.ndarray:
    """(n, B) bool: joint i carries body b (its motion, the element ending at B_i, moves it)."""
    return chain_model.of(robot).carried


def path_parameters(robot: Robot, frame: str | int) -> set[str]:
    """The parameters of the elements on the path from the root to ``frame`` (a tip's chain:
    what moves it geometrically; a mass scale, which moves it only through the moments, is not
    among them) and the motion terms of the joints on that path."""
    model = chain_model.of(robot)
    on_path = model.ancestry[model.frame_index(frame)]
    names = robot.parameter_names
    out = set()
    for k, et in enumerate(model.chain.elements):
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
    model = chain_model.of(robot)
    on_path = model.ancestry[model.frame_index(frame)]
    out = np.zeros(robot.n_joints, dtype=bool)
    for k, et in enumerate(model.chain.elements):
        if et.joint is not None and on_path[k]:
            out[et.joint] = True
    return out


def motion_offsets(robot: Robot, params: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """The joint offsets (N, n) of the motion history (fgcal.model.motion), rad or m."""
    first = chain_model.of(robot).motion_first
    if first < 0:
        raise ValueError(f"{robot.name}: its parameters have no motion terms")
    n = robot.n_joints
    return motion[:, :n] * params[first : first + n] + motion[:, n:] * params[first + n : first + 2 * n]


def forward(robot: Robot, params: np.ndarray, q: np.ndarray, motion: np.ndarray | None = None) -> KinematicsData:
    """Frames and gravity moments for parameter vector ``params`` at joint values (N, n),
    reached as the motion-history features (N, 2n) say (None: no history offsets)."""
    model = chain_model.of(robot)
    if motion is not None and not model.history:
        motion = None
    if motion is not None:
        motion = np.asarray(motion, dtype=float)
        if motion.shape != (q.shape[0], 2 * model.n_joints):
            raise ValueError(f"motion features of shape {motion.shape} for joint values of shape {q.shape}")
        q = q + motion_offsets(robot, params, motion)
    params, q = np.ascontiguousarray(params, dtype=float), np.ascontiguousarray(q, dtype=float)
    model.check(params, q)
    buffer = np.empty(model.buffer_size(q.shape[0]))
    chain_kernel.forward(model.ints, model.reals, params, q, buffer)
    return KinematicsData(model, params, q, buffer, motion)


def body_scales(robot: Robot, params: np.ndarray) -> np.ndarray:
    """(B,) each body's mass scale: its group's mass.{group} parameter, 1 outside the groups
    (the payload's mass is the robot file's)."""
    mass_param = chain_model.of(robot).mass_param
    scale = np.ones(len(mass_param))
    scaled = mass_param >= 0
    scale[scaled] = np.asarray(params, dtype=float)[mass_param[scaled]]
    return scale


def frame_index(robot: Robot, frame: str | int) -> int:
    """The index in the frames of ``frame``: flange, tool, base, or an index itself (a tree's
    tip, any frame of the chain)."""
    return chain_model.of(robot).frame_index(frame)


def frame_pose(robot: Robot, data: KinematicsData, frame: str = "flange") -> np.ndarray:
    """Pose (N, 4, 4) of ``frame`` in W."""
    return homogeneous(data.frames[data.model.frame_index(frame)])


# Empty and zero, and writable: numba's dispatch takes longer for a read-only array.
_NO_MOTION = np.zeros((1, 0))
_ORIGIN = np.zeros(3)


def spatial_jacobian(robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange") -> np.ndarray:
    """Spatial twists (N, len(wrt), 6) of ``frame`` w.r.t. each name in ``wrt``.

    Each name enters through its elements' twists on the deformed chain (a compliance times its
    gravity moment, a motion term times its motion feature). A geometric parameter, a joint or a
    mass scale also changes the gravity moments of the undeformed chain, which bend every
    deflection on the frame's path (fgcal.model.jacobian_kernel gives the formulas)."""
    return _columns(data, wrt, frame, jacobian_kernel.SPATIAL, _ORIGIN)


def jacobian(
    robot: Robot, data: KinematicsData, wrt: Sequence[str], frame: str = "flange", point: np.ndarray | None = None
) -> np.ndarray:
    """Body twist Jacobian (N, 6, T) of ``frame``, or, with ``point`` (3,) fixed in that
    frame, the Jacobian (N, 3, T) of the point's world position. See Robot.jacobian. The
    robot's tables are those ``data`` was computed with (its compiled model)."""
    if point is None:
        return _columns(data, wrt, frame, jacobian_kernel.BODY, _ORIGIN)
    point = np.asarray(point, dtype=float)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise InputError(None, "point", f"a finite point (3,) in the frame, m; got shape {point.shape}")
    return _columns(data, wrt, frame, jacobian_kernel.POINT, point)


def _columns(data: KinematicsData, wrt: Sequence[str], frame: str | int, mode: int, point: np.ndarray) -> np.ndarray:
    """The kernel's Jacobian in ``mode`` (jacobian_kernel.SPATIAL, BODY or POINT)."""
    model = data.model
    index = model.frame_names.get(frame) if type(frame) is str else None  # the common case, first
    if index is None:
        index = model.frame_index(frame)
    entries, scales = model.columns(wrt)
    n_conf, n_names = len(data.q), len(wrt)
    if mode == jacobian_kernel.SPATIAL:
        out = np.empty((n_conf, n_names, 6))
    else:
        out = np.empty((n_conf, 6 if mode == jacobian_kernel.BODY else 3, n_names))
    jacobian_kernel.jacobian(
        model.ints, model.reals, data.buffer, data.params, _NO_MOTION if data.motion is None else data.motion,
        entries, scales, index, point, mode, out,
    )  # fmt: skip
    return out


class Workspace:
    """Pinocchio's Data for the repeated evaluation of one Jacobian: the buffers an evaluation
    at ``n_conf`` configurations writes, and the Jacobian's constant arguments (its entries, the
    frame's index, the point), made once by their caller and overwritten by every
    :func:`forward_jacobian` on it. What a single configuration's FK and Jacobian cost, without a
    Python layer or an allocation per call: an IK step, an online update (docs/model.md,
    Performance). Nothing in it outlives a call but what the caller reads before the next:
    ``jacobian``, ``frames`` and ``moments`` are the last call's.

    The kernel gets it as two arrays (jacobian_kernel.forward_jacobian): the model's integer
    tables with the entries and where everything lies, and its real tables with the scales, the
    point, the evaluation's buffer and the Jacobian; ``buffer`` and ``jacobian`` are views."""

    __slots__ = ("buffer", "ints", "jacobian", "model", "n_conf", "reals", "wrt")

    def __init__(
        self, robot: Robot, wrt: Sequence[str], frame: str | int = "flange", point: np.ndarray | None = None,
        n_conf: int = 1,
    ) -> None:  # fmt: skip
        model = chain_model.of(robot)
        index = model.frame_index(frame)
        entries, scales = model.columns(wrt)
        if point is None:
            mode, point, rows = jacobian_kernel.BODY, np.zeros(3), 6
        else:
            point = np.asarray(point, dtype=float)
            if point.shape != (3,) or not np.all(np.isfinite(point)):
                raise InputError(None, "point", f"a finite point (3,) in the frame, m; got shape {point.shape}")
            mode, rows = jacobian_kernel.POINT, 3
        self.model, self.wrt, self.n_conf = model, tuple(wrt), int(n_conf)
        n_reals, size, n_out = len(model.reals), model.buffer_size(self.n_conf), self.n_conf * rows * len(self.wrt)
        at_buffer = n_reals + len(scales) + 3
        self.reals = np.concatenate([model.reals, scales, point, np.zeros(size + n_out)])
        tail = dict(
            entries=len(model.ints), n_entries=entries.shape[1], frame=index, mode=mode, scales=n_reals,
            point=n_reals + len(scales), buffer=at_buffer, out=at_buffer + size, n_conf=self.n_conf,
            n_targets=len(self.wrt), n_params=len(model.parameter_index), n_joints=model.n_joints,
        )  # fmt: skip
        self.ints = np.concatenate([model.ints, entries.reshape(-1), [tail[key] for key in jacobian_kernel.WORK_TAIL]])
        self.buffer = self.reals[at_buffer : at_buffer + size]
        # (N, 6, T) body twists or (N, 3, T) a point's rates
        self.jacobian = self.reals[at_buffer + size :].reshape(self.n_conf, rows, len(self.wrt))

    @property
    def frames(self) -> np.ndarray:
        """(K+1, N, 3, 4) the last call's deformed chain (views of the buffer)."""
        return self.model.array(self.buffer, "frames", self.n_conf)

    @property
    def moments(self) -> np.ndarray:
        """(N, 3L) the last call's gravity moments (a view of the buffer)."""
        return self.model.array(self.buffer, "moments", self.n_conf)


def forward_jacobian(
    work: Workspace, params: np.ndarray, q: np.ndarray, motion: np.ndarray | None = None
) -> np.ndarray:  # fmt: skip
    """:func:`forward` and :func:`jacobian` of ``work``'s names, frame and point in one compiled
    call, into ``work``'s buffers: its Jacobian ``work.jacobian`` (N, 6, T) or (N, 3, T), which
    the next call overwrites. ``params`` (P,) and ``q`` (N, n) float arrays of its shapes
    (ValueError otherwise, from the kernel); ``motion`` (N, 2n) the motion-history features, as
    forward's. Nothing else is done in Python: each line here costs tens of ns, of about 3 us."""
    if motion is None or not work.model.history:
        _forward_jacobian(params, q, _NO_MOTION, work.ints, work.reals)
        return work.jacobian
    motion = np.ascontiguousarray(motion, dtype=float)
    first, n = work.model.motion_first, work.model.n_joints
    if motion.shape != (q.shape[0], 2 * n):
        raise ValueError(f"motion features of shape {motion.shape} for joint values of shape {q.shape}")
    q = q + motion[:, :n] * params[first : first + n] + motion[:, n:] * params[first + n : first + 2 * n]
    _forward_jacobian(params, q, motion, work.ints, work.reals)
    return work.jacobian


_forward_jacobian = jacobian_kernel.forward_jacobian
