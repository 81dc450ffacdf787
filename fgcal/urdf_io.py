"""URDF in and out.

Import (:func:`load_urdf`): the chain from the root link to the tip link becomes a
:class:`~fgcal.robot.Robot` of :class:`~fgcal.joints.OriginJoint` s. Fixed joints fold into
the next moving joint's origin (or, after the last one, into the flange pose), so
``Robot.fk`` is the tip link's pose in the root link's frame. Every link's inertial, also
of branches off the chain (their joints at zero), is lumped into the body of the moving
joint that carries it, with its centre of mass in that body's frame.

Export (:func:`urdf_document`): links ``world``, ``base_link``, ``link_1..link_n``,
``flange`` and ``tool0``; joints ``joint_1..joint_n`` whose value is the controller's joint
value. The calibrated geometry (DH, offsets, distortions, origin corrections, base, flange
and tool) is folded exactly into the joint origins and axes, read off the robot's own
elementary transform chain at q = 0 with the compliances at zero. Compliances go to a
sidecar YAML (:func:`compliance_document`), named in a comment of the URDF.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from . import kinematics
from .errors import InputError
from .fields import read_file_text
from .joints import OriginJoint
from .outputs import output_dir, output_file, write_text
from .robot import Robot
from .se3 import inverse, rpy_from_rotation

MOVING = ("revolute", "continuous", "prismatic")
CONTINUOUS_LIMITS_RAD = (-2 * np.pi, 2 * np.pi)


def _parse(path: Path):
    """The yourdfpy model of a URDF file; malformed XML or URDF is an InputError."""
    import yourdfpy
    from lxml import etree

    text = read_file_text(path)  # a regular file of a sane size (not a FIFO, not /dev/zero)
    # yourdfpy recovers from broken XML silently: check well-formedness first, without
    # entities or network access.
    try:
        root = etree.fromstring(text.encode("utf-8"), etree.XMLParser(resolve_entities=False, no_network=True))
    except (etree.XMLSyntaxError, ValueError) as exc:
        raise InputError(path, None, f"malformed XML: {exc}") from None
    _validate(path, root)
    try:
        return yourdfpy.URDF.load(
            str(path),
            build_scene_graph=False,
            load_meshes=False,
            build_collision_scene_graph=False,
            load_collision_meshes=False,
        ).robot
    except Exception as exc:  # yourdfpy raises many kinds on a bad document
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
    """Checks yourdfpy does not make: a <robot> document, unique link and joint names, joints
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
            raise InputError(path, "tip", f"no link tool0 and several leaf links {leaves}: name the tip link")
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
    limit = joint.limit
    if limit is None or limit.lower is None or limit.upper is None:
        raise InputError(path, f"joint {joint.name}.limit", "a revolute or prismatic joint needs both limits")
    lower, upper = float(limit.lower), float(limit.upper)
    if not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
        raise InputError(path, f"joint {joint.name}.limit", f"lower {lower} must be below upper {upper}, both finite")
    return np.array([lower, upper])


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
        inertial = links[link_name].inertial
        if inertial is not None and inertial.mass is not None:
            m = float(inertial.mass)
            if not np.isfinite(m) or m < 0 or m > 1e6:
                raise InputError(path, f"link {link_name}.inertial.mass", f"must be finite, 0 to 1e6 kg, got {m}")
            com = _finite_pose(path, f"link {link_name}.inertial.origin", inertial.origin)[:3, 3]
            mass[body] += m
            first_moment[body] += m * (T_body_link[:3, :3] @ com + T_body_link[:3, 3])
        for joint in children.get(link_name, []):
            origin = _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
            if joint.name in moving:
                stack.append((joint.child, moving.index(joint.name) + 1, np.eye(4)))
            else:  # fixed, or a joint off the chain held at zero
                stack.append((joint.child, body, T_body_link @ origin))
    coms = np.divide(first_moment, mass[:, None], out=np.zeros_like(first_moment), where=mass[:, None] > 0)
    return mass[1:], coms[1:]


def load_urdf(path: str | Path, tip: str | None = None) -> Robot:
    """The robot of a URDF file: the chain from its root link to ``tip`` (default ``tool0``,
    else the only leaf link). Revolute, continuous, prismatic and fixed joints."""
    path = Path(path)
    model = _parse(path)
    if not model.joints:
        raise InputError(path, None, "the URDF has no joints")
    root, tip, chain = _chain_to(path, model, tip)
    joints, limits = [], []
    pending = np.eye(4)
    for joint in chain:
        origin = _finite_pose(path, f"joint {joint.name}.origin", joint.origin)
        if joint.type == "fixed":
            pending = pending @ origin
            continue
        if joint.type not in MOVING:
            raise InputError(path, f"joint {joint.name}.type", f"{joint.type!r} joints are not supported in the chain")
        if joint.mimic is not None:
            raise InputError(path, f"joint {joint.name}.mimic", "mimic joints are not supported in the chain")
        axis = np.asarray(joint.axis, dtype=float)
        if axis.shape != (3,) or not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-9:
            raise InputError(path, f"joint {joint.name}.axis", f"must be a non-zero finite 3-vector, got {joint.axis}")
        joints.append(OriginJoint(pending @ origin, axis, joint.type == "prismatic"))
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
    )


# -- export ------------------------------------------------------------------------------


def _comment(text: str) -> str:
    # "--" may not appear inside an XML comment.
    return "<!-- " + text.replace("--", "- -") + " -->"


def _number(value: float) -> str:
    return repr(float(value) + 0.0)


def _origin_xml(T: np.ndarray) -> str:
    xyz = " ".join(_number(v) for v in T[:3, 3])
    rpy = " ".join(_number(v) for v in rpy_from_rotation(T[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _link_xml(name: str, mass: float = 0.0, com: np.ndarray | None = None) -> str:
    if mass <= 0.0:
        return f"  <link name={quoteattr(name)}/>"
    com_xyz = " ".join(_number(v) for v in com)
    return (
        f"  <link name={quoteattr(name)}>\n"
        f'    <inertial>\n      <origin xyz="{com_xyz}" rpy="0 0 0"/>\n      <mass value="{_number(mass)}"/>\n'
        '      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>\n    </inertial>\n  </link>'
    )


def _fixed_xml(name: str, parent: str, child: str, T: np.ndarray) -> str:
    return (
        f'  <joint name={quoteattr(name)} type="fixed">\n'
        f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(child)}/>\n    {_origin_xml(T)}\n"
        "  </joint>"
    )


def joint_frames(robot: Robot) -> dict:
    """Frames of the exported URDF in W at q = 0, at the robot's parameter values with the
    compliances zero: ``base`` (T_W_0), ``joints`` (n, 4, 4: joint i's frame, its motion's
    axis through the origin), ``axes`` (n, 3: in the joint frame, signed by the joint
    direction), ``bodies`` (n, 4, 4: the frames the link masses are given in), ``bends``
    (n, 4, 4: the bending frames), ``flange`` and ``tool``."""
    chain = robot.chain
    data = kinematics.forward(robot, robot.parameter_vector(), np.zeros((1, robot.n_joints)))
    frames = data.frames_rigid[:, 0]
    motion = [next(k for k, et in enumerate(chain.elements) if et.joint == i) for i in range(robot.n_joints)]
    joints, axes = [], []
    for i, k in enumerate(motion):
        # A joint given by its origin keeps its link frame (after the axis alignment is undone).
        child = chain.link_end[i] if isinstance(robot.joints[i], OriginJoint) else k + 1
        J = frames[child]
        after_motion = frames[k + 1]
        if np.linalg.norm(J[:3, 3] - after_motion[:3, 3]) > 1e-12:
            raise ValueError(f"joint {i + 1}: the link frame is not on the joint axis")
        et = chain.elements[k]
        axis_world = et.sign * after_motion[:3, "xyz".index(et.axis[1])]
        joints.append(J)
        axes.append(J[:3, :3].T @ axis_world)
    return {
        "base": frames[chain.base_end],
        "joints": np.array(joints),
        "axes": np.array(axes),
        "bodies": frames[list(chain.link_end)],
        "bends": frames[list(chain.bend)],
        "flange": frames[chain.flange],
        "tool": frames[chain.tool],
    }


def urdf_document(robot: Robot, sidecar: str | None = None) -> str:
    """The URDF (text) of ``robot`` at its parameter values (a calibrated robot's estimates)."""
    f = joint_frames(robot)
    n = robot.n_joints
    parts = [
        '<?xml version="1.0"?>',
        _comment(
            f"Written by fgcal from {robot.name}. Joint values are the controller's (rad, m); the calibrated "
            "geometry is folded into the joint origins and axes. Inertia tensors are not modelled (zero)."
        ),
    ]
    if sidecar:
        parts.append(_comment(f"Joint compliances (gravity deflection) cannot be expressed in URDF: see {sidecar}"))
    parts.append(f"<robot name={quoteattr(robot.name)}>")
    parts += [_link_xml("world"), _link_xml("base_link")]
    parts.append(_fixed_xml("world-base_link", "world", "base_link", f["base"]))
    parent, T_parent = "base_link", f["base"]
    for i in range(n):
        link = f"link_{i + 1}"
        J = f["joints"][i]
        com_in_joint = inverse(J) @ f["bodies"][i] @ np.append(robot.coms[i], 1.0)
        parts.append(_link_xml(link, float(robot.masses[i]), com_in_joint[:3]))
        kind = "prismatic" if robot.joints[i].prismatic else "revolute"
        lower, upper = (_number(v) for v in robot.limits[i])
        axis = " ".join(_number(v) for v in f["axes"][i])
        parts.append(
            f'  <joint name="joint_{i + 1}" type="{kind}">\n'
            f'    <parent link="{parent}"/>\n    <child link="{link}"/>\n'
            f"    {_origin_xml(inverse(T_parent) @ J)}\n"
            f'    <axis xyz="{axis}"/>\n'
            f'    <limit lower="{lower}" upper="{upper}" effort="0" velocity="0"/>\n'
            "  </joint>"
        )
        parent, T_parent = link, J
    parts.append(_link_xml("flange", float(robot.payload_mass), robot.payload_com))
    parts.append(_fixed_xml(f"{parent}-flange", parent, "flange", inverse(T_parent) @ f["flange"]))
    parts.append(_link_xml("tool0"))
    parts.append(_fixed_xml("flange-tool0", "flange", "tool0", inverse(f["flange"]) @ f["tool"]))
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def compliance_document(robot: Robot, urdf_name: str) -> dict:
    """The sidecar of an exported URDF: the joint compliances (rad/(N m)) and what they mean."""
    values = robot.nominal_parameters()
    frames = joint_frames(robot)
    joints = []
    for i in range(robot.n_joints):
        B_in_joint = inverse(frames["joints"][i]) @ frames["bends"][i]
        joints.append(
            {
                "joint": f"joint_{i + 1}",
                "compliance_rad_per_Nm": [values[f"{axis}{i + 1}"] for axis in ("kx", "ky", "kz")],
                "bending_frame_rpy_rad": [float(v) + 0.0 for v in rpy_from_rotation(B_in_joint[:3, :3])],
            }
        )
    return {
        "urdf": urdf_name,
        "robot": robot.name,
        "model": robot.model,
        "meaning": (
            "Joint i deflects by Rz(kz tz) Ry(ky ty) Rx(kx tx) right after its motion, in its bending frame B_i "
            "(bending_frame_rpy_rad: B_i in the URDF joint frame; z along the joint axis). t = (tx, ty, tz) is the "
            "gravity moment (N m) that joint i carries, in B_i: the weights of the links after it and of the payload "
            "(the URDF inertials) about B_i's origin, on the undeformed chain, with gravity gravity_m_per_s2 in world."
        ),
        "gravity_m_per_s2": [float(v) for v in robot.gravity],
        "payload": {"mass_kg": float(robot.payload_mass), "com_m_in_flange": [float(v) for v in robot.payload_com]},
        "joints": joints,
    }


def export_urdf(robot: Robot, path: str | Path) -> tuple[Path, Path]:
    """Write ``path`` (URDF) and its compliance sidecar beside it (``<stem>.compliance.yaml``)."""
    import yaml

    path = Path(path)
    if path.suffix.lower() != ".urdf":
        raise InputError(path, None, "the URDF file name must end in .urdf")
    if path.is_dir():
        raise InputError(path, None, "is a folder: give the URDF file's name")
    output_dir(path.parent, None)
    sidecar = path.with_name(f"{path.stem}.compliance.yaml")
    output_file(sidecar)  # both outputs checked before either is written
    write_text(path, urdf_document(robot, sidecar.name))
    write_text(sidecar, yaml.safe_dump(compliance_document(robot, path.name), sort_keys=False))
    return path, sidecar
