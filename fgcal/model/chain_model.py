"""A robot's compiled model: everything constant about its chain, built once per robot, as
Pinocchio separates its Model from its Data (issue 37).

:class:`fgcal.model.robot.Robot` builds it once, at its first evaluation (``Robot.compiled``,
:func:`build`); the per-evaluation functions (fgcal.model.kinematics) take it from the robot and
keep nothing between calls. It holds

- the element tables (fgcal.model.ets.Layout) and the path from the root to every frame;
- the bodies (the links, then the payload): their frames, masses and centres of mass, their mass
  scales' parameters, which joint carries which body, which element moves which bodies and which
  bending frames;
- the names: each parameter's index, each named frame's index;
- all of it packed in two arrays for the compiled kernels (fgcal.model.chain_kernel's sections),
  and where each array of an evaluation lies in its buffer.

What depends on a call's arguments is computed per call, but for one thing: the Jacobian entries
of a list of names (:meth:`ChainModel.columns`) are memoised in a dict the model owns, keyed by the
names. Building them walks every element in Python (about 60 us for a full model's 78 names,
four times a single configuration's whole evaluation), and a calibration, an IK or an online
update asks for the same names at every evaluation; the key, a tuple of the names and its hash,
costs 0.65 us for the 78.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..core.errors import InputError
from . import chain_kernel as ck
from . import ets
from .ets import Chain, Layout
from .parameters import MASS_KIND, is_mass

# The arrays of one evaluation, in the order chain_kernel.evaluation_offsets places them, with
# their shapes (None: the number of configurations).
EVALUATION = ("frames_rigid", "frames", "com_world", "weighted", "torque_world", "moments", "carried_mass",
              "body_masses", "rvec_left")  # fmt: skip
_MEMO_LIMIT = 256  # lists of names memoised per model: a calibration's stages ask for a few


class Description(Protocol):
    """What the compiled model is built from (fgcal.model.robot.Robot provides it)."""

    name: str
    masses: np.ndarray
    coms: np.ndarray
    payload_mass: float
    payload_com: np.ndarray
    tip_payloads: tuple[tuple[str, float, np.ndarray], ...]
    fixed_bodies: tuple[tuple[str, int, float, np.ndarray], ...]
    gravity: np.ndarray
    compliant: bool
    history: bool
    mass_groups: tuple[tuple[str, tuple[int, ...]], ...]

    @property
    def chain(self) -> Chain: ...

    @property
    def n_joints(self) -> int: ...

    @property
    def parameter_names(self) -> list[str]: ...


@dataclass(frozen=True, eq=False)
class ChainModel:
    """The constant tables of one robot's chain (SI units); see the module's docstring.

    Bodies b: the L links (body i: the link of joint i, in frame ``body_frame[i]``), then the
    payload on the flange, the tips' payloads and the fixed bodies. ``carried`` (L, B): joint i
    carries body b (its last motion element, chain.carriers, moves it); element k moves the bodies
    ``set_bodies[moved_set[k]]`` (S, B: the distinct sets); ``moves_bend`` (L, K) the elements
    that move each bending frame ``bend``.
    """

    name: str
    chain: Chain
    layout: Layout
    body_frame: np.ndarray  # (B,) each body's frame
    bend: np.ndarray  # (L,) each joint's bending frame B_i
    carried: np.ndarray  # (L, B) bool
    moved_set: np.ndarray  # (K,)
    set_bodies: np.ndarray  # (S, B) bool
    moves_bend: np.ndarray  # (L, K) bool
    masses: np.ndarray  # (B,) kg, before the mass scales
    coms: np.ndarray  # (B, 3) m, each in its body's frame
    mass_param: np.ndarray  # (B,) the parameter of each body's mass scale, -1: none
    gravity: np.ndarray  # (3,) m/s^2 in W
    parameter_index: dict[str, int]
    frame_names: dict[str, int]  # flange, tool, base and the named tips
    n_joints: int  # the joints the controller moves
    compliant: bool
    history: bool
    motion_first: int  # the index of lm1 (-1: no motion terms)
    ints: np.ndarray  # the integer tables packed for the kernels (chain_kernel's sections); never written
    reals: np.ndarray  # the real ones
    evaluation: dict[str, tuple[int, int, tuple]]  # array: (a, b, shape): it starts at a + b N
    _columns: dict[tuple, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    @property
    def ancestry(self) -> np.ndarray:
        """(K+1, K) bool: element k lies on the path from the root to frame f."""
        return self.layout.ancestry

    @property
    def n_links(self) -> int:
        return len(self.bend)

    def buffer_size(self, n_conf: int) -> int:
        """The floats one evaluation at ``n_conf`` configurations takes."""
        a, b, _ = self.evaluation["end"]
        return a + b * n_conf

    def check(self, params: np.ndarray, q: np.ndarray) -> None:
        """ValueError unless ``params`` (P,) and ``q`` (N, n) cover every index of the tables."""
        layout = self.layout
        if params.ndim != 1 or len(params) < layout.n_params or q.ndim != 2 or q.shape[1] < layout.n_joints:
            layout.check(params, q)  # the message

    def array(self, buffer: np.ndarray, name: str, n_conf: int) -> np.ndarray:
        """The array ``name`` (one of :data:`EVALUATION`) of an evaluation, a view of ``buffer``."""
        a, b, shape = self.evaluation[name]
        shape = tuple(n_conf if size is None else size for size in shape)
        start = a + b * n_conf
        return buffer[start : start + int(np.prod(shape))].reshape(shape)

    def frame_index(self, frame: str | int) -> int:
        """The index in the frames of ``frame``: flange, tool, base, a named tip, or an index itself."""
        if isinstance(frame, (int, np.integer)) and not isinstance(frame, bool):
            n_elements = len(self.chain.elements)
            if not 0 <= frame <= n_elements:
                raise InputError(None, "frame", f"no frame {frame} in a chain of {n_elements} elements")
            return int(frame)
        index = self.frame_names.get(frame) if isinstance(frame, str) else None
        if index is None:
            named = [name for name, _ in self.chain.tips]
            tips = f", or a tip: {', '.join(named)}" if len(named) > 1 else ""
            raise InputError(None, "frame", f"unknown frame {frame!r} (flange, tool or base{tips})")
        return index

    def columns(self, wrt: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian entries of the names ``wrt`` (jacobian_kernel.ENTRY_ROWS, (6, E)) and
        their scales (E,), memoised by the names (see the module's docstring)."""
        key = tuple(wrt)
        found = self._columns.get(key)
        if found is None:
            found = self._entries(key)
            if len(self._columns) >= _MEMO_LIMIT:
                self._columns.clear()
            self._columns[key] = found
        return found

    def _entries(self, wrt: tuple) -> tuple[np.ndarray, np.ndarray]:
        """Each name's entries (target, element, column, feature, moment, mass) and scales: a
        joint ``q{j}`` enters through its motions (scaled by their signs or coupling
        coefficients), a motion term through its joint's, scaled by its motion feature, a
        parameter through its elements, a mass scale through the moments alone."""
        elements = self.chain.elements
        by_param: dict[int, list[tuple[int, int]]] = {}
        by_joint: dict[int, list[tuple[int, float]]] = {}
        for k, et in enumerate(elements):
            if et.axis == "Rvec":
                for c in range(3):
                    by_param.setdefault(et.param + c, []).append((k, c))
            elif et.param is not None:
                by_param.setdefault(et.param, []).append((k, 0))
            if et.joint is not None:
                by_joint.setdefault(et.joint, []).append((k, et.sign))
        n, first_motion, index = self.n_joints, self.motion_first, self.parameter_index
        rows: list[tuple[int, int, int, int, int, int]] = []
        scales: list[float] = []

        def enter(target: int, through: list[tuple[int, float]], feature: int = -1) -> None:
            for k, scale in through:
                rows.append((target, k, 0, feature, -1 if elements[k].moment is None else elements[k].moment, -1))
                scales.append(scale)

        for t, name in enumerate(wrt):
            if name.startswith("q") and name[1:].isdigit():
                joint = int(name[1:]) - 1
                if not 0 <= joint < n:
                    raise InputError(None, "wrt", f"{self.name} has no joint {name}")
                enter(t, by_joint.get(joint, []))
            elif name in index and 0 <= first_motion <= index[name] < first_motion + 2 * n:
                feature = index[name] - first_motion
                enter(t, by_joint.get(feature % n, []), feature)
            elif name in index and is_mass(name):
                rows.append((t, -1, 0, -1, -1, index[name]))
                scales.append(1.0)
            elif name in index:
                for k, c in by_param.get(index[name], []):
                    rows.append((t, k, c, -1, -1 if elements[k].moment is None else elements[k].moment, -1))
                    scales.append(1.0)
            else:
                raise InputError(None, "wrt", f"unknown parameter or joint name {name!r}")
        entries = np.array(rows, dtype=np.int64).reshape(-1, 6).T.copy()
        scale_array = np.array(scales, dtype=float)
        return entries, scale_array


def build(robot: Description) -> ChainModel:
    """The compiled model of ``robot``'s chain (fgcal.model.robot.Robot.compiled calls it once)."""
    chain = robot.chain
    layout = ets.layout(chain.elements)
    paths = layout.ancestry
    tip_frames = dict(chain.tips)
    extra = getattr(robot, "tip_payloads", ()), getattr(robot, "fixed_bodies", ())
    body_frame = np.array(
        [*chain.link_end, chain.flange, *(tip_frames[tip] for tip, _, _ in extra[0]),
         *(chain.base_end if joint < 0 else chain.link_end[joint] for _, joint, _, _ in extra[1])],
        dtype=np.int64,
    )  # fmt: skip
    bend = np.array(chain.bend, dtype=np.int64)
    moved = paths[body_frame]  # (B, K): element k moves body b
    set_bodies, moved_set = np.unique(moved.T, axis=0, return_inverse=True)
    carried = np.ascontiguousarray(moved[:, np.array(chain.carriers, dtype=np.int64)].T)
    names = list(robot.parameter_names)
    index = {name: k for k, name in enumerate(names)}
    masses = np.array(
        [*robot.masses, robot.payload_mass, *(m for _, m, _ in extra[0]), *(m for _, _, m, _ in extra[1])], dtype=float
    )
    coms = np.ascontiguousarray(
        np.vstack([robot.coms, robot.payload_com, *(c for _, _, c in extra[0]), *(c for _, _, _, c in extra[1])]),
        dtype=float,
    ).reshape(-1, 3)
    mass_param = np.full(len(masses), -1, dtype=np.int64)
    for group, members in robot.mass_groups:
        mass_param[list(members)] = index[f"{MASS_KIND}.{group}"]
    gravity = np.asarray(robot.gravity, dtype=float).reshape(3)
    n_rvecs = layout.n_rvecs
    ints, reals = _pack(
        {
            ck.ELEMENTS: layout.tables, ck.ANCESTRY: paths, ck.BODIES: [body_frame, mass_param], ck.BENDS: [bend],
            ck.CARRIED: carried, ck.MOVES_BEND: paths[bend], ck.BODY_SETS: set_bodies,
            ck.MOVED_SET: [moved_set.reshape(-1)], ck.FLAGS: [[int(robot.compliant), n_rvecs]],
        },
        {ck.CONSTANTS: layout.constants, ck.COMS: coms, ck.MASSES: [masses], ck.GRAVITY: [gravity]},
    )  # fmt: skip
    frame_names = {**dict(chain.tips), "flange": chain.flange, "tool": chain.tool, "base": chain.base_end}
    model = ChainModel(
        name=robot.name, chain=chain, layout=layout, body_frame=body_frame, bend=bend, carried=carried,
        moved_set=moved_set.reshape(-1).astype(np.int64), set_bodies=np.ascontiguousarray(set_bodies),
        moves_bend=paths[bend], masses=masses, coms=coms, mass_param=mass_param, gravity=gravity,
        parameter_index=index, frame_names=frame_names, n_joints=robot.n_joints, compliant=bool(robot.compliant),
        history=bool(robot.history), motion_first=index.get("lm1", -1), ints=ints, reals=reals,
        evaluation=_evaluation_layout(len(chain.elements) + 1, len(bend), len(masses), n_rvecs, robot.compliant),
    )  # fmt: skip
    for array in (body_frame, bend, carried, model.moved_set, model.set_bodies, model.moves_bend, masses, coms,
                  mass_param, gravity):  # fmt: skip
        array.flags.writeable = False  # shared by every evaluation of the robot
    return model


def of(robot: Description) -> ChainModel:
    """``robot``'s compiled model: its own (``Robot.compiled``, built once); a description that
    holds none (a test's hand-built tree) gets one built for this call."""
    model = getattr(robot, "compiled", None)
    return build(robot) if model is None else model


def _pack(int_tables: dict[int, object], real_tables: dict[int, object]) -> tuple[np.ndarray, np.ndarray]:
    """The sections of chain_kernel as its two arrays: the header (offset, rows, columns per
    section) and the integer tables in one, the real tables in the other, each C-ordered.
    Nothing writes them, yet they stay writable (as the Jacobian entries do): numba's dispatch
    takes about 25 ns longer for each read-only array, at every call."""
    header = np.zeros(ck.HEADER, dtype=np.int64)
    packed: dict[type, list[np.ndarray]] = {np.int64: [header], np.float64: []}
    ends = {np.int64: ck.HEADER, np.float64: 0}
    for tables, dtype in ((int_tables, np.int64), (real_tables, np.float64)):
        for which, table in tables.items():
            array = np.asarray(table, dtype=dtype)
            array = array.reshape(1, -1) if array.ndim < 2 else array
            header[3 * which : 3 * which + 3] = ends[dtype], array.shape[0], array.shape[1]
            packed[dtype].append(array.reshape(-1))
            ends[dtype] += array.size
    if set(int_tables) | set(real_tables) != set(range(ck.N_SECTIONS)):
        raise ValueError("every section of the compiled model is packed once")
    ints, reals = np.concatenate(packed[np.int64]), np.concatenate(packed[np.float64])
    return ints, reals


def _evaluation_layout(n_frames: int, n_links: int, n_bodies: int, n_rvecs: int, compliant: bool) -> dict:
    """Each evaluation array's (a, b, shape), from chain_kernel.evaluation_offsets itself (run as
    Python): its offsets are linear in the number of configurations N."""
    at = [ck.evaluation_offsets.py_func(n_frames, n, n_links, n_bodies, n_rvecs, int(compliant)) for n in (0, 1)]
    shapes = [(n_frames, None, 3, 4), (n_frames, None, 3, 4), (None, n_bodies, 3), (None, n_bodies, 3),
              (None, n_links, 3), (None, 3 * n_links), (n_links,), (n_bodies,), (n_rvecs, 3, 3), ()]  # fmt: skip
    return {name: (at[0][k], at[1][k] - at[0][k], shapes[k]) for k, name in enumerate((*EVALUATION, "end"))}
