"""URDF in and out.

Reading: the file (a ``*.xacro`` expanded first: fgcal.model.xacro_io) is parsed (lxml,
well-formed XML only) and checked (:func:`read_document`),
then read into a small model of its own (:func:`_parse`: links with their mass and centre of
mass, joints with type, parent, child, origin, axis, limits and mimic), with the URDF defaults:
no ``<origin>`` is the identity, a missing ``xyz`` or ``rpy`` is zeros, ``rpy`` is fixed-axis
Rz(yaw) Ry(pitch) Rx(roll), no ``<axis>`` is (1, 0, 0).

Import (:func:`load_urdf`): the chain from the root link to the tip link becomes a
:class:`~fgcal.model.robot.Robot` of :class:`~fgcal.model.joints.OriginJoint` s. A URDF with several leaf
links and no tip named (nor a ``tool0``) becomes a tree (:func:`load_urdf_tree`): every moving
joint, each hanging from the moving joint before it, and every leaf link a named tip. Fixed joints fold into
the next moving joint's origin (or, after the last one, into the flange pose), so
``Robot.fk`` is the tip link's pose in the root link's frame. Every link's inertial, also
of branches off the chain (their joints at zero), is lumped into the body of the moving
joint that carries it, with its centre of mass in that body's frame.

Export: fgcal.model.urdf_export.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import read_file_text
from ..core.se3 import pose_from_xyz_rpy
from .joints import OriginJoint
from .robot import Robot
from .xacro_io import expand, is_xacro

MOVING = ("revolute", "continuous", "prismatic")
CONTINUOUS_LIMITS_RAD = (-2 * np.pi, 2 * np.pi)


def read_document(path: Path):
    """The checked XML tree (lxml, comments and layout kept) of a URDF file; malformed XML or
    an invalid document is an InputError."""
    from lxml import etree

    if is_xacro(path):  # a vendor's xacro, expanded (fgcal.model.xacro_io)
        text, _ = expand(path)
    else:
        text = read_file_text(path)  # a regular file of a sane size (not a FIFO, not /dev/zero)
    # Well-formed XML only (no recovery from broken XML), without entities or network access.
    try:
        tree = etree.ElementTree(
            etree.fromstring(text.encode("utf-8"), etree.XMLParser(resolve_entities=False, no_network=True))
        )
    except (etree.XMLSyntaxError, ValueError) as exc:
        raise InputError(path, None, f"malformed XML: {exc}") from None
    _validate(path, tree.getroot())
    return tree


@dataclass(frozen=True)
class _Link:
    name: str
    mass: float | None  # kg; None: no <inertial> or no <mass> in it
    com_origin: np.ndarray  # 4x4: the inertial frame (centre of mass) in the link's


@dataclass(frozen=True)
class _Joint:
    name: str
    type: str | None
    parent: str
    child: str
    origin: np.ndarray  # 4x4: the child link's frame in the parent's at zero
    axis: np.ndarray  # (3,)
    lower: float | None
    upper: float | None
    mimic: bool


@dataclass(frozen=True)
class _Model:
    name: str
    links: tuple[_Link, ...]
    joints: tuple[_Joint, ...]


# Numbers of a URDF that fgcal does not use, read all the same: a file in which they are not
# numbers is refused.
_UNUSED_NUMBERS = {
    "inertia": ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"),
    "limit": ("effort", "velocity"),
    "mimic": ("multiplier", "offset"),
    "calibration": ("rising", "falling"),
    "safety_controller": ("soft_lower_limit", "soft_upper_limit", "k_position", "k_velocity"),
}


def _check_unused(element, tags: tuple[str, ...]) -> None:
    for tag in tags:
        child = element.find(tag)
        for key in _UNUSED_NUMBERS[tag] if child is not None else ():
            if (text := child.get(key)) is not None:
                float(text)


def _origin(element) -> np.ndarray:
    """The pose of an ``<origin>``: the identity if there is none, a missing xyz or rpy zeros."""
    if element is None:
        return np.eye(4)
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()]
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()]
    return pose_from_xyz_rpy(np.array(xyz), np.array(rpy))


def _optional_float(text: str | None) -> float | None:
    return None if text is None else float(text)


def _read_model(root) -> _Model:
    """The model of a checked URDF tree (:func:`_validate`). A number that is not one, or a
    <robot> without a name, raises ValueError or KeyError."""
    name = root.attrib["name"]
    links = []
    for element in root.findall("link"):
        inertial = element.find("inertial")
        mass, com_origin = None, np.eye(4)
        if inertial is not None:
            com_origin = _origin(inertial.find("origin"))
            _check_unused(inertial, ("inertia",))
            mass_element = inertial.find("mass")
            if mass_element is not None:
                mass = float(mass_element.get("value", "0"))
        links.append(_Link(element.get("name"), mass, com_origin))
    joints = []
    for element in root.findall("joint"):
        axis = element.find("axis")
        limit = element.find("limit")
        _check_unused(element, ("limit", "mimic", "calibration", "safety_controller"))
        joints.append(
            _Joint(
                name=element.get("name"),
                type=element.get("type"),
                parent=element.find("parent").get("link"),
                child=element.find("child").get("link"),
                origin=_origin(element.find("origin")),
                axis=np.array([float(v) for v in ("1 0 0" if axis is None else axis.get("xyz", "1 0 0")).split()]),
                lower=None if limit is None else _optional_float(limit.get("lower")),
                upper=None if limit is None else _optional_float(limit.get("upper")),
                mimic=element.find("mimic") is not None,
            )
        )
    return _Model(name, tuple(links), tuple(joints))


def _parse(path: Path) -> _Model:
    """The model of a URDF file; malformed XML or URDF is an InputError."""
    root = read_document(path).getroot()
    try:
        return _read_model(root)
    except (KeyError, ValueError) as exc:  # a <robot> without a name, a number that is not one
        raise InputError(path, None, f"not a valid URDF: {type(exc).__name__}: {exc}") from None


# What a number of a URDF may be: an origin within 1 km, an angle within 100 rad, a joint's
# limits within 1000 (rad or m). Anything beyond is a typo or a sentinel, not a robot.
MAX_TRANSLATION_M, MAX_ANGLE_RAD, MAX_LIMIT = 1e3, 100.0, 1e3


def _numbers(path: Path, where: str, text: str | None, count: int, bound: float) -> None:
    if text is None:
        return
    parts = text.split()
    try:
        values = [float(v) for v in parts]
    except ValueError:
        values = []
    if len(parts) != count or len(values) != count or not all(np.isfinite(v) and abs(v) <= bound for v in values):
        raise InputError(
            path, where, f"expected {count} finite number{'s' if count > 1 else ''} within {bound:g}, got {text!r}"
        )


def _validate(path: Path, root) -> None:
    """The checks of a URDF's structure and numbers: a <robot> document, unique link and joint names, joints
    between links that exist, origins, axes and limits of the right length and size."""
    if root.tag != "robot":
        raise InputError(path, None, f"not a URDF: the document is <{root.tag}>, not <robot>")
    for kind in ("link", "joint"):
        names = [element.get("name") for element in root.findall(kind)]
        if any(not name for name in names):
            raise InputError(path, kind, f"a <{kind}> without a name")
        repeated = sorted(name for name, count in Counter(names).items() if count > 1)
        if repeated:
            raise InputError(path, f"{kind} {repeated[0]}", f"two <{kind}> elements are named {repeated[0]!r}")
    links = {element.get("name") for element in root.findall("link")}
    for joint in root.findall("joint"):
        name = joint.get("name")
        for end in ("parent", "child"):
            element = joint.find(end)
            if element is None or element.get("link") not in links:
                got = None if element is None else element.get("link")
                raise InputError(path, f"joint {name}.{end}", f"no link {got!r}")
        origin = joint.find("origin")
        if origin is not None:
            _numbers(path, f"joint {name}.origin.xyz", origin.get("xyz"), 3, MAX_TRANSLATION_M)
            _numbers(path, f"joint {name}.origin.rpy", origin.get("rpy"), 3, MAX_ANGLE_RAD)
        axis = joint.find("axis")
        if axis is not None:
            _numbers(path, f"joint {name}.axis", axis.get("xyz"), 3, 1e6)
        limit = joint.find("limit")
        if limit is not None:
            for key in ("lower", "upper"):
                _numbers(path, f"joint {name}.limit.{key}", limit.get(key), 1, MAX_LIMIT)
    parent_of: dict[str, str] = {}
    for joint in root.findall("joint"):
        child = joint.find("child").get("link")
        if child in parent_of:
            raise InputError(path, f"joint {joint.get('name')}.child", f"link {child!r} is the child of two joints")
        parent_of[child] = joint.find("parent").get("link")
    rooted: set[str] = set()  # links whose way up ends at a root
    for start in parent_of:  # a tree: walking up from any link ends at the root
        walked: set[str] = set()
        link = start
        while link in parent_of and link not in rooted:
            if link in walked:
                raise InputError(path, f"link {start}", "the joints form a loop: a URDF is a tree")
            walked.add(link)
            link = parent_of[link]
        rooted |= walked
    for link in root.findall("link"):
        for origin in link.iter("origin"):
            _numbers(path, f"link {link.get('name')}.origin.xyz", origin.get("xyz"), 3, MAX_TRANSLATION_M)
            _numbers(path, f"link {link.get('name')}.origin.rpy", origin.get("rpy"), 3, MAX_ANGLE_RAD)


def _finite_pose(path: Path, where: str, pose: np.ndarray | None) -> np.ndarray:
    pose = np.eye(4) if pose is None else np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)) or np.abs(pose[:3, 3]).max() > 1e3:
        raise InputError(path, where, "origin must be finite, within 1 km")
    return pose


def _chain_to(path: Path, model, tip: str | None) -> tuple[str, str, list]:
    """Root link, tip link and the joints from root to tip."""
    links = {link.name for link in model.links}
    by_child = {}
    for joint in model.joints:
        if joint.child in by_child:
            raise InputError(path, f"joint {joint.name}", f"link {joint.child!r} has two parent joints")
        by_child[joint.child] = joint
    roots = sorted(links - set(by_child))
    if len(roots) != 1:
        raise InputError(path, None, f"a URDF robot has exactly one root link, found {roots}")
    parents = {joint.parent for joint in model.joints}
    if tip is None:
        leaves = sorted(links - parents)
        if "tool0" in links:
            tip = "tool0"
        elif len(leaves) == 1:
            tip = leaves[0]
        else:
            raise _SeveralLeavesError(leaves)
    if tip not in links:
        raise InputError(path, "tip", f"no link {tip!r} (links: {', '.join(sorted(links))})")
    chain, link = [], tip
    while link in by_child:
        chain.append(by_child[link])
        link = by_child[link].parent
        if len(chain) > len(model.joints):
            raise InputError(path, None, "the joints form a loop")
    return roots[0], tip, chain[::-1]


def _joint_limits(path: Path, joint) -> np.ndarray:
    if joint.type == "continuous":
        return np.array(CONTINUOUS_LIMITS_RAD)
    if joint.lower is None or joint.upper is None:
        raise InputError(path, f"joint {joint.name}.limit", "a revolute or prismatic joint needs both limits")
    lower, upper = joint.lower, joint.upper
    if not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
        raise InputError(path, f"joint {joint.name}.limit", f"lower {lower} must be below upper {upper}, both finite")
    return np.array([lower, upper])


def _moving_joint(path: Path, joint, pending: np.ndarray) -> OriginJoint:
    """A moving joint as an OriginJoint whose origin is ``pending`` (the fixed joints before it
    in its parent's link) times its own."""
    if joint.type not in MOVING:
        raise InputError(path, f"joint {joint.name}.type", f"{joint.type!r} joints are not supported")
    if joint.mimic:
        raise InputError(path, f"joint {joint.name}.mimic", "mimic joints are not supported yet")
    axis = np.asarray(joint.axis, dtype=float)
    if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-9:
        raise InputError(path, f"joint {joint.name}.axis", f"must be a non-zero finite 3-vector, got {joint.axis}")
    origin = _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
    return OriginJoint(pending @ origin, axis, joint.type == "prismatic")


def load_urdf_tree(path: str | Path, tips: list[str] | None = None) -> Robot:
    """The tree of a URDF: every moving joint (depth first from the root, children in the
    file's order), each hanging from the moving joint whose link carries it, and the ``tips``
    (default every leaf link, the deepest first) as named frames; the first tip is the flange.
    Each link's inertial goes to the body of the moving joint that carries it."""
    path = Path(path)
    model = _parse(path)
    links = {link.name: link for link in model.links}
    children: dict[str, list] = {}
    has_parent = set()
    for joint in model.joints:
        if joint.child in has_parent:
            raise InputError(path, f"joint {joint.name}", f"link {joint.child!r} has two parent joints")
        has_parent.add(joint.child)
        children.setdefault(joint.parent, []).append(joint)
    roots = sorted(set(links) - has_parent)
    if len(roots) != 1:
        raise InputError(path, None, f"a URDF robot has exactly one root link, found {roots}")
    for name in tips or []:
        if name not in links:
            raise InputError(path, "tips", f"no link {name!r} (links: {', '.join(sorted(links))})")
    joints, limits, parents, names, where = [], [], [], [], {}
    body_mass: dict[int, float] = {}
    body_moment: dict[int, np.ndarray] = {}
    # Depth first (pre-order, children in the file's order) with a stack of its own: each entry is
    # a link, the moving joint carrying it (-1: none), its pose in that joint's link frame, and
    # the moving joint that leads to it (numbered when reached: after the joint it hangs from).
    stack = [(roots[0], -1, np.eye(4), None)]
    visited = 0
    while stack:
        link_name, body, T_body_link, leading = stack.pop()
        visited += 1
        if visited > len(links):
            raise InputError(path, None, "the joints form a loop")
        if leading is not None:
            joints.append(_moving_joint(path, leading, T_body_link))
            limits.append(_joint_limits(path, leading))
            parents.append(body)
            names.append(leading.name)
            body, T_body_link = len(joints) - 1, np.eye(4)
        link = links[link_name]
        where[link_name] = (body, T_body_link)
        if link.mass is not None:
            m, moment = _link_inertial(path, link, T_body_link)
            body_mass[body] = body_mass.get(body, 0.0) + m
            body_moment[body] = body_moment.get(body, np.zeros(3)) + moment
        reached = []
        for joint in children.get(link_name, []):
            if joint.type == "fixed":
                origin = _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
                reached.append((joint.child, body, T_body_link @ origin, None))
            else:
                reached.append((joint.child, body, T_body_link, joint))
        stack.extend(reversed(reached))  # popped in the file's order
    if not joints:
        raise InputError(path, None, "the URDF has no moving joint")
    n = len(joints)

    def depth(link_name: str) -> int:  # moving joints between the root and the link
        count, joint = 0, where[link_name][0]
        while joint >= 0:
            count, joint = count + 1, parents[joint]
        return count

    # By default every leaf, the deepest first (the flange: the end of the longest chain).
    leaves = sorted(set(links) - set(children), key=lambda name: (-depth(name), name))
    wanted = leaves if tips is None else list(tips)
    masses = np.array([body_mass.get(j, 0.0) for j in range(n)])
    moments = np.array([body_moment.get(j, np.zeros(3)) for j in range(n)])
    coms = np.divide(moments, masses[:, None], out=np.zeros_like(moments), where=masses[:, None] > 0)
    flange_joint, flange_pose = where[wanted[0]]
    return Robot(
        name=model.name or path.stem,
        joints=tuple(joints),
        directions=np.ones(n),
        limits=np.array(limits),
        masses=masses,
        coms=coms,
        flange_pose=flange_pose,
        source=f"URDF {path.name}: tree from {roots[0]}, tips {', '.join(wanted)}; joints {', '.join(names)}",
        urdf=(str(path.resolve()), wanted[0]),
        parents=tuple(parents),
        flange_joint=flange_joint,
        tips=tuple((name, *where[name]) for name in wanted[1:]),
        flange_name=wanted[0],
    )


def _link_inertial(path: Path, link, T_body_link: np.ndarray) -> tuple[float, np.ndarray]:
    """A link's mass (kg, checked) and first mass moment (kg m) in the body frame it is lumped
    into, the link at ``T_body_link`` there."""
    m = link.mass
    if not np.isfinite(m) or m < 0 or m > 1e6:
        raise InputError(path, f"link {link.name}.inertial.mass", f"must be finite, 0 to 1e6 kg, got {m}")
    com = _finite_pose(path, f"link {link.name}.inertial.origin", link.com_origin)[:3, 3]
    return m, m * (T_body_link[:3, :3] @ com + T_body_link[:3, 3])


def _lumped_inertials(path: Path, model, chain: list) -> tuple[np.ndarray, np.ndarray]:
    """Mass (kg) and centre of mass (m, in the body frame) of each moving joint's body."""
    moving = [joint.name for joint in chain if joint.type in MOVING]
    links = {link.name: link for link in model.links}
    children: dict[str, list] = {}
    for joint in model.joints:
        children.setdefault(joint.parent, []).append(joint)
    mass = np.zeros(len(moving) + 1)  # entry 0: links that never move
    first_moment = np.zeros((len(moving) + 1, 3))

    # Depth first with a stack of its own: a tree thousands of links deep is no recursion limit.
    stack = [(chain[0].parent, 0, np.eye(4))]
    while stack:
        link_name, body, T_body_link = stack.pop()
        link = links[link_name]
        if link.mass is not None:
            m, moment = _link_inertial(path, link, T_body_link)
            mass[body] += m
            first_moment[body] += moment
        for joint in children.get(link_name, []):
            origin = _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
            if joint.name in moving:
                stack.append((joint.child, moving.index(joint.name) + 1, np.eye(4)))
            else:  # fixed, or a joint off the chain held at zero
                stack.append((joint.child, body, T_body_link @ origin))
    coms = np.divide(first_moment, mass[:, None], out=np.zeros_like(first_moment), where=mass[:, None] > 0)
    return mass[1:], coms[1:]


class _SeveralLeavesError(Exception):
    """A URDF with several leaf links and no tip named: a tree."""

    def __init__(self, leaves: list[str]) -> None:
        super().__init__(f"several leaf links {leaves}")


def load_urdf(path: str | Path, tip: str | None = None) -> Robot:
    """The robot of a URDF file: the chain from its root link to ``tip`` (default ``tool0``,
    else the only leaf link); with several leaves and no tip, the tree of every moving joint
    with every leaf a named tip (:func:`load_urdf_tree`). Revolute, continuous, prismatic and
    fixed joints."""
    path = Path(path)
    model = _parse(path)
    if not model.joints:
        raise InputError(path, None, "the URDF has no joints")
    try:
        root, tip, chain = _chain_to(path, model, tip)
    except _SeveralLeavesError:
        return load_urdf_tree(path)  # every leaf a tip
    joints, limits = [], []
    pending = np.eye(4)
    for joint in chain:
        if joint.type == "fixed":
            pending = pending @ _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
            continue
        joints.append(_moving_joint(path, joint, pending))
        limits.append(_joint_limits(path, joint))
        pending = np.eye(4)
    if not joints:
        raise InputError(path, "tip", f"no moving joint between {root} and {tip}")
    masses, coms = _lumped_inertials(path, model, chain)
    return Robot(
        name=model.name or path.stem,
        joints=tuple(joints),
        directions=np.ones(len(joints)),
        limits=np.array(limits),
        masses=masses,
        coms=coms,
        flange_pose=pending,
        source=f"URDF {path.name}: chain {root} -> {tip}",
        urdf=(str(path.resolve()), tip),
    )
