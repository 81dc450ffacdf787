"""The named parameters of SPEC section 2 and their kinds.

A DH joint i (1-based) has ``theta{i} d{i} a{i} alpha{i} sx{i} sy{i} kx{i} ky{i} kz{i}``; a
joint given by its origin (URDF) has ``theta{i}`` (``d{i}`` if prismatic), the origin
correction ``tx{i} ty{i} tz{i} rx{i} ry{i} rz{i}`` and the compliances (fgcal.model.joints).
Every joint also has the motion-history terms ``lm{i} lv{i}`` (fgcal.model.motion: lost motion and
the speed term, rad or m), listed after all the joints' geometry: one pair per joint the
controller moves (a coupled joint follows others and has none). ``mass.{group}`` scales the masses
of a group of bodies the robot file names (1 = as declared; model DH,s,e: the gravity moments the
compliances bend under). ``frame.{name}.*`` are the same six for a fixed frame the robot file
names (a constant transform before a joint's row, or a tip's pose), and ``base.*`` and ``tool.*``
local perturbations of the nominal base and tool poses, translation (m) then rotation vector (rad).
A joint whose deflection another joint's moment drives has a coupled compliance ``kc{i}``.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

JOINT_KINDS = ("theta", "d", "a", "alpha", "sx", "sy", "kx", "ky", "kz")
ORIGIN_CORRECTION_KINDS = ("tx", "ty", "tz", "rx", "ry", "rz")
POSE_KINDS = ("tx", "ty", "tz", "rx", "ry", "rz")
LENGTH_KINDS = frozenset({"d", "a", "tx", "ty", "tz"})
COMPLIANCE_KINDS = frozenset({"kx", "ky", "kz", "kc"})
COUPLED_COMPLIANCE = "kc"  # joint i deflects about its bending frame's z by kc_i times another joint's z moment
FRAME = "frame"  # a fixed frame's perturbation: frame.{name}.tx .. rz
MOTION_KINDS = ("lm", "lv")  # fgcal.model.motion
MASS_KIND = "mass"  # a body group's mass scale (1)
_JOINT_NAME = re.compile(r"^(theta|d|a|alpha|sx|sy|kx|ky|kz|kc|tx|ty|tz|rx|ry|rz|lm|lv)([1-9][0-9]*)$")
_FRAME_NAME = re.compile(r"^(frame\.[A-Za-z_][A-Za-z0-9_]*)\.(tx|ty|tz|rx|ry|rz)$")
FRAME_LABEL = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")  # what a fixed frame may be called
_POSE_NAME = re.compile(r"^(base|tool)\.(tx|ty|tz|rx|ry|rz)$")
_MASS_NAME = re.compile(r"^mass\.([A-Za-z_][A-Za-z0-9_]*)$")


def parameter_names(
    joint_kinds: Sequence[Sequence[str]],
    n_moved: int | None = None,
    mass_groups: Sequence[str] = (),
    frames: Sequence[str] = (),
) -> list[str]:
    """All parameter names, in the order of the parameter vector: the kinds of each joint
    (fgcal.model.joints), the motion-history terms of each of the ``n_moved`` joints the controller
    moves (default: every joint), the mass scales of the body groups, the fixed frames'
    perturbations, then base and tool."""
    n_moved = len(joint_kinds) if n_moved is None else n_moved
    names = [f"{kind}{i}" for i, kinds in enumerate(joint_kinds, start=1) for kind in kinds]
    names += [f"{kind}{i}" for kind in MOTION_KINDS for i in range(1, n_moved + 1)]
    names += [f"{MASS_KIND}.{group}" for group in mass_groups]
    names += [f"{FRAME}.{frame}.{kind}" for frame in frames for kind in POSE_KINDS]
    names += [f"{pose}.{kind}" for pose in ("base", "tool") for kind in POSE_KINDS]
    return names


def is_joint_length(name: str) -> bool:
    """A length of the arm itself (d, a, an origin translation): what length bounds limit;
    base and tool translations are free."""
    kind, owner = split_name(name)
    return isinstance(owner, int) and kind in LENGTH_KINDS


def split_name(name: str) -> tuple[str, int | str]:
    """``'alpha3' -> ('alpha', 3)``, ``'base.rx' -> ('rx', 'base')``, ``'mass.arms' ->
    ('mass', 'arms')``, ``'frame.l_mount.tz' -> ('tz', 'frame.l_mount')``; ValueError otherwise."""
    match = _JOINT_NAME.match(name)
    if match:
        return match.group(1), int(match.group(2))
    match = _FRAME_NAME.match(name)
    if match:
        return match.group(2), match.group(1)
    match = _POSE_NAME.match(name)
    if match:
        return match.group(2), match.group(1)
    match = _MASS_NAME.match(name)
    if match:
        return MASS_KIND, match.group(1)
    raise ValueError(f"unknown parameter name {name!r}")


def kind_label(name: str) -> str:
    """What a stage or a group calls a parameter: its kind (``theta``, ``kx``, ``mass``), or
    ``base``/``tool``/``frame`` for a pose's perturbation."""
    kind, owner = split_name(name)
    if isinstance(owner, str) and owner.startswith(f"{FRAME}."):
        return FRAME
    return owner if isinstance(owner, str) and kind != MASS_KIND else kind


def is_mass(name: str) -> bool:
    """A body group's mass scale."""
    return name.startswith(f"{MASS_KIND}.")


def unit_of(name: str) -> str:
    """SI unit of a parameter value (the motion terms of a prismatic joint are m, not rad)."""
    kind, _ = split_name(name)
    if kind in LENGTH_KINDS:
        return "m"
    if kind in COMPLIANCE_KINDS:
        return "rad/(N m)"
    if kind == MASS_KIND:
        return "1"
    return "rad"


def default_compliant_joints(n_joints: int) -> tuple[int, ...]:
    """The joints whose compliances are candidates when nothing says otherwise: the seed's
    1-3, those the robot has (a 2-axis positioner has 1 and 2)."""
    return tuple(j for j in (1, 2, 3) if j <= n_joints)


def moment_column(name: str) -> int:
    """The column of a compliance's driving moment in KinematicsData.moments (N, 3n): joint i's
    x, y, z components are columns 3(i-1) .. 3(i-1)+2. A coupled compliance kc{i}: its own
    joint's z column (another joint's moment drives it, of the same order: what a plausible
    deviation needs)."""
    kind, joint = split_name(name)
    return 3 * (int(joint) - 1) + ("xyz".index(kind[1]) if kind != COUPLED_COMPLIANCE else 2)


def is_frame(name: str) -> bool:
    """A fixed frame's perturbation (frame.{name}.*)."""
    return name.startswith(f"{FRAME}.")


def is_motion(name: str) -> bool:
    """A motion-history term (lm, lv) of a joint."""
    return split_name(name)[0] in MOTION_KINDS
