"""Elementary transform sequence (ETS): the one mechanism behind DH, the extended
model, base, tool and any other serial chain.

A chain is a tuple of :class:`ET`. Each element is a rotation about or translation along
one principal axis of the frame before it, with value (rad or m)::

    value = const + p[param] * (moment[:, moment] if moment is set else 1) + sign * q[:, joint]

or, for ``Rvec``, a rotation by the rotation vector ``p[param:param+3]``. Gravity
deflections are elements whose parameter (a compliance, rad/(N m)) is scaled by a
per-configuration gravity moment (N m).

Evaluation is vectorised over N configurations: ``frames[k]`` is the pose, in the chain's
root frame, of the frame *before* element k (``frames[K]`` is the chain's end).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .se3 import cross, so3_exp, so3_left_jacobian

AXES = ("Rx", "Ry", "Rz", "Tx", "Ty", "Tz", "Rvec")


@dataclass(frozen=True)
class ET:
    """One elementary transform. ``param``/``joint``/``moment`` are indices or None."""

    axis: str
    const: float = 0.0
    param: int | None = None
    joint: int | None = None
    sign: float = 1.0
    moment: int | None = None

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


def element_values(chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray) -> np.ndarray:
    """Scalar values (N, K) of the chain's elements (0 for Rvec elements)."""
    n_conf = q.shape[0]
    values = np.zeros((n_conf, len(chain)))
    for k, et in enumerate(chain):
        if et.axis == "Rvec":
            continue
        value = np.full(n_conf, et.const)
        if et.param is not None:
            scale = moments[:, et.moment] if et.moment is not None else 1.0
            value = value + params[et.param] * scale
        if et.joint is not None:
            value = value + et.sign * q[:, et.joint]
        values[:, k] = value
    return values


def evaluate(
    chain: tuple[ET, ...], params: np.ndarray, q: np.ndarray, moments: np.ndarray, root: np.ndarray | None = None
) -> np.ndarray:
    """Frames (K+1, N, 4, 4) along the chain for N configurations ``q`` (N, n_joints)."""
    values = element_values(chain, params, q, moments)
    n_conf = q.shape[0]
    frames = np.empty((len(chain) + 1, n_conf, 4, 4))
    frames[0] = np.eye(4) if root is None else root
    for k, et in enumerate(chain):
        current = frames[k].copy()
        v = values[:, k]
        if et.axis == "Rvec":
            current[:, :3, :3] = current[:, :3, :3] @ so3_exp(params[et.param : et.param + 3])
        elif et.is_rotation:
            # Right-multiplying by a principal rotation mixes two columns of the rotation.
            i = et.axis_index
            j, m = (i + 1) % 3, (i + 2) % 3
            c, s = np.cos(v)[:, None], np.sin(v)[:, None]
            col_j, col_m = current[:, :3, j].copy(), current[:, :3, m].copy()
            current[:, :3, j] = c * col_j + s * col_m
            current[:, :3, m] = -s * col_j + c * col_m
        else:
            current[:, :3, 3] += v[:, None] * current[:, :3, et.axis_index]
        frames[k + 1] = current
    return frames


def element_twists(chain: tuple[ET, ...], params: np.ndarray, frames: np.ndarray) -> list[np.ndarray]:
    """Spatial unit twists of each element in the root frame.

    For element k the entry has shape (N, c, 6) with c = 1 (c = 3 for Rvec): rows
    ``[omega, v0]`` such that a point p downstream of the element moves by
    ``dp = omega x p + v0`` per unit change of the element's value.
    """
    twists = []
    for k, et in enumerate(chain):
        rot = frames[k][:, :3, :3]
        origin = frames[k][:, :3, 3]
        n_conf = rot.shape[0]
        if et.axis == "Rvec":
            omega = rot @ so3_left_jacobian(params[et.param : et.param + 3])  # (N, 3, 3): columns
            omega = np.swapaxes(omega, 1, 2)  # (N, 3 columns, 3)
            v0 = -cross(omega, origin[:, None, :])
            twists.append(np.concatenate([omega, v0], axis=-1))
            continue
        axis = rot[:, :, et.axis_index]
        twist = np.zeros((n_conf, 1, 6))
        if et.is_rotation:
            twist[:, 0, :3] = axis
            twist[:, 0, 3:] = -cross(axis, origin)
        else:
            twist[:, 0, 3:] = axis
        twists.append(twist)
    return twists
