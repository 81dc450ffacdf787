"""The named parameters of SPEC section 2 and their kinds.

Joint i (1-based) has ``theta{i} d{i} a{i} alpha{i} sx{i} sy{i} kx{i} ky{i} kz{i}``;
``base.*`` and ``tool.*`` are local perturbations of the nominal base and tool poses,
translation (m) then rotation vector (rad).
"""

from __future__ import annotations

import re

JOINT_KINDS = ("theta", "d", "a", "alpha", "sx", "sy", "kx", "ky", "kz")
POSE_KINDS = ("tx", "ty", "tz", "rx", "ry", "rz")
LENGTH_KINDS = frozenset({"d", "a", "tx", "ty", "tz"})
COMPLIANCE_KINDS = frozenset({"kx", "ky", "kz"})
_JOINT_NAME = re.compile(r"^(theta|d|a|alpha|sx|sy|kx|ky|kz)([1-9][0-9]*)$")
_POSE_NAME = re.compile(r"^(base|tool)\.(tx|ty|tz|rx|ry|rz)$")


def parameter_names(n_joints: int) -> list[str]:
    """All parameter names, in the order of the parameter vector."""
    names = [f"{kind}{i}" for i in range(1, n_joints + 1) for kind in JOINT_KINDS]
    names += [f"{pose}.{kind}" for pose in ("base", "tool") for kind in POSE_KINDS]
    return names


def split_name(name: str) -> tuple[str, int | str]:
    """``'alpha3' -> ('alpha', 3)``, ``'base.rx' -> ('rx', 'base')``; ValueError otherwise."""
    match = _JOINT_NAME.match(name)
    if match:
        return match.group(1), int(match.group(2))
    match = _POSE_NAME.match(name)
    if match:
        return match.group(2), match.group(1)
    raise ValueError(f"unknown parameter name {name!r}")


def unit_of(name: str) -> str:
    """SI unit of a parameter value."""
    kind, _ = split_name(name)
    if kind in LENGTH_KINDS:
        return "m"
    if kind in COMPLIANCE_KINDS:
        return "rad/(N m)"
    return "rad"


def default_compliant_joints(n_joints: int) -> tuple[int, ...]:
    """The joints whose compliances are candidates when nothing says otherwise: the seed's
    1-3, those the robot has (a 2-axis positioner has 1 and 2)."""
    return tuple(j for j in (1, 2, 3) if j <= n_joints)
