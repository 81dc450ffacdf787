"""Joint geometries: how one joint of a robot description becomes elementary transforms.

A robot is a sequence of joints of either kind, each with its own named parameters:

- :class:`DHJoint` (SPEC section 2): ``Rx(sx) Ry(sy) Rz(s q + theta) | Tz(d) Tx(a) Rx(alpha)``;
  parameters ``theta d a alpha sx sy kx ky kz``.
- :class:`ModifiedDHJoint` (Craig's convention): ``Rx(alpha) Tx(a) Rx(sx) Ry(sy) Rz(s q + theta)
  | Tz(d)``, where alpha and a are the twist and length of the link before the joint (Craig's
  alpha_{i-1}, a_{i-1}); the same parameter names.
- :class:`OriginJoint` (as URDF gives a joint): the nominal origin of the joint frame in
  the previous link's frame, a unit axis and a type. The chain is
  ``origin  T(tx,ty,tz) Exp(rx,ry,rz)  A  Rz(q + theta) | A^-1`` for a revolute joint, with
  ``A`` the constant rotation taking z onto the axis, and ``Tz(q + d)`` for a prismatic one;
  parameters ``theta`` (or ``d``) ``tx ty tz rx ry rz kx ky kz``: the joint offset, a
  small correction of the origin (m, rad; the identifiability analysis removes the
  redundant directions) and the compliances.

``|`` marks the bending frame B_i, where the gravity deflection ``Rz(kz tz) Ry(ky ty)
Rx(kx tx)`` enters (added by :func:`fgcal.model.robot.build_chain`, the same for every kind).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..core.se3 import rpy_from_rotation
from .ets import ET
from .parameters import JOINT_KINDS, ORIGIN_CORRECTION_KINDS

DH_KINDS = JOINT_KINDS
ORIGIN_KINDS = ("theta", *ORIGIN_CORRECTION_KINDS, "kx", "ky", "kz")
PRISMATIC_KINDS = ("d", *ORIGIN_CORRECTION_KINDS, "kx", "ky", "kz")

ParamIndex = Callable[[str], int]  # kind -> index in the parameter vector


def pose_elements(pose: np.ndarray) -> list[ET]:
    """A constant pose as elements ``Tx Ty Tz Rz(yaw) Ry(pitch) Rx(roll)`` (zeros dropped)."""
    xyz = pose[:3, 3]
    roll, pitch, yaw = rpy_from_rotation(pose[:3, :3])
    fixed = [ET("Tx", xyz[0]), ET("Ty", xyz[1]), ET("Tz", xyz[2]), ET("Rz", yaw), ET("Ry", pitch), ET("Rx", roll)]
    return [et for et in fixed if et.const != 0.0]


def perturbation_elements(first_param: int) -> list[ET]:
    """A 6-parameter local perturbation: translation (m) then rotation vector (rad)."""
    return [
        ET("Tx", param=first_param),
        ET("Ty", param=first_param + 1),
        ET("Tz", param=first_param + 2),
        ET("Rvec", param=first_param + 3),
    ]


@dataclass(frozen=True)
class _DHRow:
    """The four numbers of a DH row (rad, m), in either convention."""

    theta: float
    d: float
    a: float
    alpha: float

    kinds = DH_KINDS
    prismatic = False
    # What a fixed frame right before the row duplicates exactly (a rotation about the axes the
    # row starts with, a translation along its z, which the motion keeps).
    framed: tuple[str, ...] = ("theta", "d", "sx", "sy")
    # What fixed frames on every branch leaving the link duplicate exactly: the motion's offset
    # and what follows it.
    carrying: tuple[str, ...] = ("theta", "d", "a", "alpha")

    def nominal(self) -> dict[str, float]:
        return {"theta": self.theta, "d": self.d, "a": self.a, "alpha": self.alpha}


@dataclass(frozen=True)
class DHJoint(_DHRow):
    """A revolute joint in Denavit-Hartenberg form (rad, m)."""

    def before_bend(self, param: ParamIndex, joint: int, sign: float, distortions: bool) -> list[ET]:
        elements = [ET("Rx", param=param("sx")), ET("Ry", param=param("sy"))] if distortions else []
        return [*elements, ET("Rz", param=param("theta"), joint=joint, sign=sign)]

    def after_bend(self, param: ParamIndex) -> list[ET]:
        return [ET("Tz", param=param("d")), ET("Tx", param=param("a")), ET("Rx", param=param("alpha"))]


@dataclass(frozen=True)
class ModifiedDHJoint(_DHRow):
    """A revolute joint in modified (Craig) DH form (rad, m): ``alpha`` and ``a`` come before
    the joint's motion, ``d`` after it."""

    framed = ("alpha", "a", "sx", "sy", "theta", "d")
    carrying = ("theta", "d")

    def before_bend(self, param: ParamIndex, joint: int, sign: float, distortions: bool) -> list[ET]:
        link = [ET("Rx", param=param("alpha")), ET("Tx", param=param("a"))]
        tilt = [ET("Rx", param=param("sx")), ET("Ry", param=param("sy"))] if distortions else []
        return [*link, *tilt, ET("Rz", param=param("theta"), joint=joint, sign=sign)]

    def after_bend(self, param: ParamIndex) -> list[ET]:
        return [ET("Tz", param=param("d"))]


@dataclass(frozen=True, eq=False)
class OriginJoint:
    """A revolute or prismatic joint given by its origin (4x4 pose of the joint frame in
    the previous link's frame, m) and unit axis in the joint frame."""

    origin: np.ndarray
    axis: np.ndarray
    prismatic: bool = False

    def __post_init__(self) -> None:
        norm = float(np.linalg.norm(self.axis))
        if not np.isfinite(norm) or norm < 1e-9:
            raise ValueError(f"joint axis must be a non-zero finite vector, got {self.axis}")
        object.__setattr__(self, "axis", np.asarray(self.axis, float) / norm)
        object.__setattr__(self, "origin", np.asarray(self.origin, float))

    @property
    def kinds(self) -> tuple[str, ...]:
        return PRISMATIC_KINDS if self.prismatic else ORIGIN_KINDS

    @property
    def framed(self) -> tuple[str, ...]:
        """What a fixed frame right before the joint duplicates exactly: its origin's correction
        and its offset."""
        return (*ORIGIN_CORRECTION_KINDS, "d" if self.prismatic else "theta")

    @property
    def carrying(self) -> tuple[str, ...]:
        """What fixed frames on every branch leaving the joint's link duplicate exactly."""
        return ("d" if self.prismatic else "theta",)

    def nominal(self) -> dict[str, float]:
        return {}

    def _alignment(self) -> tuple[float, float]:
        """Angles (phi, beta) with ``Rz(phi) Ry(beta) e_z = axis``."""
        x, y, z = self.axis
        beta = float(np.arccos(np.clip(z, -1.0, 1.0)))
        phi = float(np.arctan2(y, x)) if np.hypot(x, y) > 1e-15 else 0.0
        return phi, beta

    def before_bend(self, param: ParamIndex, joint: int, sign: float, distortions: bool) -> list[ET]:
        # distortions: the origin's rotation correction already tilts the axis.
        phi, beta = self._alignment()
        align = [et for et in (ET("Rz", phi), ET("Ry", beta)) if et.const != 0.0]
        if self.prismatic:
            motion = ET("Tz", param=param("d"), joint=joint, sign=sign)
        else:
            motion = ET("Rz", param=param("theta"), joint=joint, sign=sign)
        return [*pose_elements(self.origin), *perturbation_elements(param("tx")), *align, motion]

    def after_bend(self, param: ParamIndex) -> list[ET]:
        phi, beta = self._alignment()
        return [et for et in (ET("Ry", -beta), ET("Rz", -phi)) if et.const != 0.0]


Joint = DHJoint | ModifiedDHJoint | OriginJoint
