"""Elementary transform sequence (ETS): the one mechanism behind DH, the extended
model, base, tool and any other serial chain.

A chain is a tuple of :class:`ET`. Each element is a rotation about or translation along
one principal axis of the frame before it, with value (rad or m)::

    value = const + p[param] * (moment[:, moment] if moment is set else 1) + sign * q[:, joint]

or, for ``Rvec``, a rotation by the rotation vector ``p[param:param+3]``. Gravity
deflections are elements whose parameter (a compliance, rad/(N m)) is scaled by a
per-configuration gravity moment (N m).

Evaluation (the compiled loops of fgcal.model.chain_kernel) covers N configurations: ``frames[k + 1]``
is the pose, in the chain's root frame, of the frame *after* element k, and ``frames[0]`` the
root. An element starts from the frame before it (``frames[k]``) or, with ``parent`` set, from
any earlier frame: a sequence with parents is a tree (a torso with two arms, a robot and its
positioner), each branch starting where it leaves the trunk, and a serial chain is the tree
without them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import chain_kernel

AXES = ("Rx", "Ry", "Rz", "Tx", "Ty", "Tz", "Rvec")


@dataclass(frozen=True)
class ET:
    """One elementary transform. ``param``/``joint``/``moment`` are indices or None;
    ``parent`` the frame it starts from (None: the frame before it)."""

    axis: str
    const: float = 0.0
    param: int | None = None
    joint: int | None = None
    sign: float = 1.0
    moment: int | None = None
    parent: int | None = None

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise ValueError(f"unknown elementary transform axis {self.axis!r}")
        if self.axis == "Rvec" and (self.param is None or self.joint is not None or self.moment is not None):
            raise ValueError("an Rvec element takes three parameters and nothing else")

    @property
    def is_rotation(self) -> bool:
        return self.axis[0] == "R"

    @property
    def axis_index(self) -> int:
        return "xyz".index(self.axis[1]) if self.axis != "Rvec" else -1


@dataclass(frozen=True)
class Layout:
    """A chain as the compiled kernel's tables (fgcal.model.chain_kernel): one column per element,
    -1 for "none". ``tables`` (6, K) holds the integer rows, ``constants`` (2, K) the real ones,
    each row also named below. A robot's are built once, in its compiled model
    (fgcal.model.chain_model); :func:`layout` builds them for any sequence."""

    tables: np.ndarray  # (6, K) kind, param, moment, joint, start, rvec_slot
    constants: np.ndarray  # (2, K) const, sign
    ancestry: np.ndarray  # (K+1, K) element k lies on the path from the root to frame f
    n_params: int  # the parameters, joints and moments the indices reach
    n_joints: int
    n_moments: int

    @property
    def kind(self) -> np.ndarray:
        return self.tables[0]  # 0..2 Rx..Rz, 3..5 Tx..Tz, 6 Rvec

    @property
    def param(self) -> np.ndarray:
        return self.tables[1]  # parameter index (an Rvec's first of three)

    @property
    def moment(self) -> np.ndarray:
        return self.tables[2]  # the gravity moment that scales the parameter

    @property
    def joint(self) -> np.ndarray:
        return self.tables[3]

    @property
    def start(self) -> np.ndarray:
        return self.tables[4]  # the frame each element starts from (k for a serial chain)

    @property
    def rvec_slot(self) -> np.ndarray:
        return self.tables[5]  # the element's row among the rotation vectors (-1: not one)

    @property
    def n_rvecs(self) -> int:
        return int(np.count_nonzero(self.kind == AXES.index("Rvec")))

    @property
    def const(self) -> np.ndarray:
        return self.constants[0]

    @property
    def sign(self) -> np.ndarray:
        return self.constants[1]  # the joint's sign

    def check(self, params: np.ndarray, q: np.ndarray, moments: np.ndarray | None = None) -> None:
        """ValueError unless the arrays cover every index of the tables: the compiled kernel
        does not check its bounds, and would read past them. ``moments`` None: the kernel
        computes them (fgcal.model.kinematics.forward)."""
        if params.ndim != 1 or len(params) < self.n_params:
            raise ValueError(f"{self.n_params} parameters needed, got shape {params.shape}")
        if q.ndim != 2 or q.shape[1] < self.n_joints:
            raise ValueError(f"joint values (N, {self.n_joints}) needed, got shape {q.shape}")
        if moments is not None and (
            moments.ndim != 2 or len(moments) != len(q) or 0 < moments.shape[1] < self.n_moments
        ):
            raise ValueError(f"moments (N, 0) or (N, {self.n_moments}) needed, got shape {moments.shape}")


def layout(chain: tuple[ET, ...]) -> Layout:
    """The kernel's tables of ``chain``, built anew at each call (a robot holds its own, built
    once: fgcal.model.chain_model)."""
    start = np.array([k if et.parent is None else et.parent for k, et in enumerate(chain)], dtype=np.int64)
    if np.any((start < 0) | (start > np.arange(len(chain)))):
        raise ValueError("an element starts from a frame that is not before it")
    paths = np.zeros((len(chain) + 1, len(chain)), dtype=bool)
    for k in range(len(chain)):  # frame k + 1 is reached through element k and the path to its start
        paths[k + 1] = paths[start[k]]
        paths[k + 1, k] = True
    rvecs = [k for k, et in enumerate(chain) if et.axis == "Rvec"]
    slot = np.full(len(chain), -1, dtype=np.int64)
    slot[rvecs] = np.arange(len(rvecs))

    def indices(field: str) -> np.ndarray:
        return np.array([-1 if getattr(et, field) is None else getattr(et, field) for et in chain], dtype=np.int64)

    kind = np.array([AXES.index(et.axis) for et in chain], dtype=np.int64)
    out = Layout(
        tables=np.array([kind, indices("param"), indices("moment"), indices("joint"), start, slot], dtype=np.int64),
        constants=np.array(
            [[et.const for et in chain], [et.sign if et.joint is not None else 0.0 for et in chain]], dtype=float
        ).reshape(2, -1),
        ancestry=paths,
        n_params=max([et.param + (3 if et.axis == "Rvec" else 1) for et in chain if et.param is not None], default=0),
        n_joints=max([et.joint + 1 for et in chain if et.joint is not None], default=0),
        n_moments=max([et.moment + 1 for et in chain if et.moment is not None], default=0),
    )
    for array in (out.tables, out.constants, out.ancestry):
        array.flags.writeable = False  # shared by every evaluation of the chain
    return out


def ancestry(chain: tuple[ET, ...]) -> np.ndarray:
    """(K+1, K) bool: ``[f, k]`` element k lies on the path from the root to frame f (what
    moves frame f); for a serial chain, k < f. Built anew (a robot's: its chain_model's)."""
    return layout(chain).ancestry


def _as_floats(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array, dtype=float)


def evaluate(
    chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray, root: np.ndarray | None = None
) -> np.ndarray:
    """Frames (K+1, N, 4, 4) along the chain for N configurations ``q`` (N, n_joints); the
    gravity moments (N, 3L) scale the deflections (with none, (N, 0), each deflection is its
    parameter's value). Builds the chain's tables at each call: a robot's evaluations go
    through fgcal.model.kinematics.forward and its compiled model."""
    chain_layout = layout(chain)
    params, q, moments = _as_floats(params), _as_floats(q), _as_floats(moments)
    chain_layout.check(params, q, moments)
    frames = np.empty((len(chain) + 1, q.shape[0], 3, 4))
    root = ROOT if root is None else _as_floats(root)
    chain_kernel.frames(chain_layout.tables, chain_layout.constants, params, q, moments, True, root, frames)
    return homogeneous(frames)


def homogeneous(frames: np.ndarray) -> np.ndarray:
    """(..., 4, 4) transforms from their top three rows (..., 3, 4)."""
    out = np.zeros((*frames.shape[:-2], 4, 4))
    out[..., :3, :] = frames
    out[..., 3, 3] = 1.0
    return out


ROOT = np.eye(4)  # the root frame of a chain evaluated without one
ROOT.flags.writeable = False


@dataclass(frozen=True)
class Chain:
    """An elementary transform chain with the frame indices the model needs.

    ``frames[link_end[i]]`` is frame i+1 (after joint i+1, 0-based i), ``frames[bend[i]]``
    the bending frame B_{i+1} right after the joint motion, ``frames[base_end]`` the
    robot base frame 0, ``frames[flange]`` the flange n and ``frames[tool]`` the tool frame
    (by default the end of the sequence); ``tips`` the named frames of a tree (name, index);
    ``carrier[i]`` joint i+1's (last) motion element, which moves every body the joint carries
    (default ``bend[i] - 1``: a deflection after the motion; one about the parent's axes comes
    before it).
    """

    elements: tuple[ET, ...]
    base_end: int
    bend: tuple[int, ...]
    link_end: tuple[int, ...]
    flange: int
    tool_frame: int | None = None
    tips: tuple[tuple[str, int], ...] = ()
    carrier: tuple[int, ...] = ()

    @property
    def carriers(self) -> tuple[int, ...]:
        return self.carrier if self.carrier else tuple(b - 1 for b in self.bend)

    @property
    def tool(self) -> int:
        return len(self.elements) if self.tool_frame is None else self.tool_frame
