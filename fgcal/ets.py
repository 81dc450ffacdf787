"""Elementary transform sequence (ETS): the one mechanism behind DH, the extended
model, base, tool and any other serial chain.

A chain is a tuple of :class:`ET`. Each element is a rotation about or translation along
one principal axis of the frame before it, with value (rad or m)::

    value = const + p[param] * (moment[:, moment] if moment is set else 1) + sign * q[:, joint]

or, for ``Rvec``, a rotation by the rotation vector ``p[param:param+3]``. Gravity
deflections are elements whose parameter (a compliance, rad/(N m)) is scaled by a
per-configuration gravity moment (N m).

Evaluation is vectorised over N configurations: ``frames[k + 1]`` is the pose, in the chain's
root frame, of the frame *after* element k, and ``frames[0]`` the root. An element starts from
the frame before it (``frames[k]``) or, with ``parent`` set, from any earlier frame: a sequence
with parents is a tree (a torso with two arms, a robot and its positioner), each branch starting
where it leaves the trunk, and a serial chain is the tree without them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .se3 import cross, so3_exp, so3_left_jacobian

# An Rvec element's rotation and its left Jacobian depend on its three parameters alone (a base
# or tool perturbation), which stay the same over an IK's or an online update's evaluations.


@lru_cache(maxsize=256)
def _rotation_of(key: bytes) -> np.ndarray:
    out = so3_exp(np.frombuffer(key))
    out.flags.writeable = False
    return out


@lru_cache(maxsize=256)
def _left_jacobian_of(key: bytes) -> np.ndarray:
    out = so3_left_jacobian(np.frombuffer(key))
    out.flags.writeable = False
    return out


def _rotation(rotation_vector: np.ndarray) -> np.ndarray:
    return _rotation_of(np.ascontiguousarray(rotation_vector, dtype=float).tobytes())


def _left_jacobian(rotation_vector: np.ndarray) -> np.ndarray:
    return _left_jacobian_of(np.ascontiguousarray(rotation_vector, dtype=float).tobytes())


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
class _Layout:
    """Static index arrays of a chain, so that evaluation loops over elements only where
    it must (the cumulative product)."""

    const: np.ndarray  # (K,)
    param: np.ndarray  # (K,) parameter index, or 0 with has_param False
    has_param: np.ndarray
    moment: np.ndarray  # (K,) moment index, or 0 with has_moment False
    has_moment: np.ndarray
    joint: np.ndarray
    joint_sign: np.ndarray  # (K,) sign, or 0 without a joint
    axis: np.ndarray  # (K,) 0, 1, 2 (0 for Rvec)
    rotations: tuple[np.ndarray, np.ndarray, np.ndarray]  # element indices of Rx, Ry, Rz
    translations: tuple[np.ndarray, np.ndarray, np.ndarray]
    is_rotation: np.ndarray  # (K,) Rx/Ry/Rz (not Rvec)
    rvecs: tuple[int, ...]
    start: np.ndarray  # (K,) the frame each element starts from (k for a serial chain)
    ancestry: np.ndarray  # (K+1, K) element k lies on the path from the root to frame f


# Up to this many configurations, evaluation multiplies the elements' 4x4 transforms.
_FEW = 8

_LAYOUTS: dict[int, tuple[tuple[ET, ...], _Layout]] = {}


def _layout(chain: tuple[ET, ...]) -> _Layout:
    # Keyed on identity: hashing a chain hashes every element, which costs more than a
    # single-configuration evaluation. The entry keeps the chain alive, so ids stay unique.
    entry = _LAYOUTS.get(id(chain))
    if entry is None or entry[0] is not chain:
        if len(_LAYOUTS) > 256:
            _LAYOUTS.clear()
        entry = _LAYOUTS[id(chain)] = (chain, _make_layout(chain))
    return entry[1]


def _make_layout(chain: tuple[ET, ...]) -> _Layout:
    def indices(axis: str) -> np.ndarray:
        return np.array([k for k, et in enumerate(chain) if et.axis == axis], dtype=int)

    start = np.array([k if et.parent is None else et.parent for k, et in enumerate(chain)], dtype=int)
    if np.any((start < 0) | (start > np.arange(len(chain)))):
        raise ValueError("an element starts from a frame that is not before it")
    ancestry = np.zeros((len(chain) + 1, len(chain)), dtype=bool)
    for k in range(len(chain)):  # frame k + 1 is reached through element k and the path to its start
        ancestry[k + 1] = ancestry[start[k]]
        ancestry[k + 1, k] = True

    return _Layout(
        const=np.array([et.const for et in chain], dtype=float),
        param=np.array([et.param or 0 for et in chain], dtype=int),
        has_param=np.array([et.param is not None and et.axis != "Rvec" for et in chain]),
        moment=np.array([et.moment or 0 for et in chain], dtype=int),
        has_moment=np.array([et.moment is not None for et in chain]),
        joint=np.array([et.joint or 0 for et in chain], dtype=int),
        joint_sign=np.array([et.sign if et.joint is not None else 0.0 for et in chain], dtype=float),
        axis=np.array([max(et.axis_index, 0) for et in chain], dtype=int),
        rotations=tuple(indices(a) for a in ("Rx", "Ry", "Rz")),
        translations=tuple(indices(a) for a in ("Tx", "Ty", "Tz")),
        is_rotation=np.array([et.axis in ("Rx", "Ry", "Rz") for et in chain]),
        rvecs=tuple(k for k, et in enumerate(chain) if et.axis == "Rvec"),
        start=start,
        ancestry=ancestry,
    )


def ancestry(chain: tuple[ET, ...]) -> np.ndarray:
    """(K+1, K) bool: ``[f, k]`` element k lies on the path from the root to frame f (what
    moves frame f); for a serial chain, k < f."""
    return _layout(chain).ancestry


def element_values(chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray) -> np.ndarray:
    """Scalar values (N, K) of the chain's elements (0 for Rvec elements)."""
    layout = _layout(chain)
    scale = np.where(layout.has_moment, moments[:, layout.moment], 1.0) if moments.shape[1] else 1.0
    by_param = np.where(layout.has_param, params[layout.param], 0.0) * scale
    return layout.const + by_param + layout.joint_sign * q[:, layout.joint]


def element_transforms(chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray) -> np.ndarray:
    """Local transforms (K, N, 4, 4) of the chain's elements."""
    layout = _layout(chain)
    values = element_values(chain, params, q, moments).T  # (K, N)
    transforms = np.zeros((len(chain), q.shape[0], 4, 4))
    transforms[..., [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    for i, rows in enumerate(layout.rotations):
        if rows.size:
            j, m = (i + 1) % 3, (i + 2) % 3
            c, s = np.cos(values[rows]), np.sin(values[rows])
            transforms[rows, :, j, j] = c
            transforms[rows, :, m, m] = c
            transforms[rows, :, j, m] = -s
            transforms[rows, :, m, j] = s
    for i, rows in enumerate(layout.translations):
        if rows.size:
            transforms[rows, :, i, 3] = values[rows]
    for k in layout.rvecs:
        transforms[k, :, :3, :3] = _rotation(params[chain[k].param : chain[k].param + 3])
    return transforms


def evaluate(
    chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray, root: np.ndarray | None = None
) -> np.ndarray:
    """Frames (K+1, N, 4, 4) along the chain for N configurations ``q`` (N, n_joints)."""
    n_conf = q.shape[0]
    layout = _layout(chain)
    frames = np.empty((len(chain) + 1, n_conf, 4, 4))
    frames[0] = np.eye(4) if root is None else root
    if n_conf <= _FEW:
        transforms = element_transforms(chain, params, q, moments)
        for k in range(len(chain)):
            np.matmul(frames[layout.start[k]], transforms[k], out=frames[k + 1])
        return frames
    # Many configurations: numpy's stacked 4x4 matmul is slow per matrix, so each element
    # updates only what it changes (two columns of the rotation, or the origin).
    values = element_values(chain, params, q, moments).T[..., None]  # (K, N, 1)
    cosines, sines = np.cos(values), np.sin(values)
    for k, et in enumerate(chain):
        before = frames[layout.start[k]]
        current = frames[k + 1]
        current[:] = before
        if et.axis == "Rvec":
            current[:, :3, :3] = before[:, :3, :3] @ _rotation(params[et.param : et.param + 3])
        elif layout.is_rotation[k]:
            i = layout.axis[k]
            j, m = (i + 1) % 3, (i + 2) % 3
            col_j, col_m = before[:, :3, j], before[:, :3, m]
            current[:, :3, j] = cosines[k] * col_j + sines[k] * col_m
            current[:, :3, m] = cosines[k] * col_m - sines[k] * col_j
        else:
            current[:, :3, 3] += values[k] * before[:, :3, layout.axis[k]]
    return frames


def element_twists(chain: tuple[ET, ...], params: np.ndarray, frames: np.ndarray) -> list[np.ndarray]:
    """Spatial unit twists of each element in the root frame.

    For element k the entry has shape (N, c, 6) with c = 1 (c = 3 for Rvec): rows
    ``[omega, v0]`` such that a point p downstream of the element moves by
    ``dp = omega x p + v0`` per unit change of the element's value.
    """
    layout = _layout(chain)
    n_elements = len(chain)
    origin = frames[layout.start, :, :3, 3]  # (K, N, 3): each element's own starting frame
    axis = frames[layout.start, :, :3, layout.axis]  # (K, N, 3)
    twists = np.zeros((n_elements, frames.shape[1], 1, 6))
    rotation = layout.is_rotation
    twists[rotation, :, 0, :3] = axis[rotation]
    twists[rotation, :, 0, 3:] = -cross(axis[rotation], origin[rotation])
    twists[~rotation, :, 0, 3:] = axis[~rotation]
    out = list(twists)
    for k in layout.rvecs:
        rot = frames[layout.start[k]][:, :3, :3]
        omega = rot @ _left_jacobian(params[chain[k].param : chain[k].param + 3])  # (N, 3, 3): columns
        omega = np.swapaxes(omega, 1, 2)  # (N, 3 columns, 3)
        v0 = -cross(omega, origin[k][:, None, :])
        out[k] = np.concatenate([omega, v0], axis=-1)
    return out


@dataclass(frozen=True)
class Chain:
    """An elementary transform chain with the frame indices the model needs.

    ``frames[link_end[i]]`` is frame i+1 (after joint i+1, 0-based i), ``frames[bend[i]]``
    the bending frame B_{i+1} right after the joint motion, ``frames[base_end]`` the
    robot base frame 0, ``frames[flange]`` the flange n and ``frames[tool]`` the tool frame
    (by default the end of the sequence); ``tips`` the named frames of a tree (name, index).
    """

    elements: tuple[ET, ...]
    base_end: int
    bend: tuple[int, ...]
    link_end: tuple[int, ...]
    flange: int
    tool_frame: int | None = None
    tips: tuple[tuple[str, int], ...] = ()

    @property
    def tool(self) -> int:
        return len(self.elements) if self.tool_frame is None else self.tool_frame
