"""URDF out: the calibrated robot for ROS, MoveIt and simulators.

Two documents, both with the calibrated geometry (DH, offsets, distortions, origin
corrections) folded exactly into joint origins (and axes), read off the robot's own elementary
transform chain at q = 0 with the compliances at zero:

- a robot that came from a URDF (``Robot.urdf``, or a template given): **that document**, with
  only the origins of the chain's moving joints changed. Names, links, meshes, limits,
  inertias, transmissions, ros2_control and gazebo blocks are kept (:func:`faithful_document`);
- any other robot: links ``world``, ``base_link``, ``link_1..link_n``, ``flange`` and
  ``tool0`` (ROS-Industrial names); joints ``joint_1..joint_n`` whose value is the
  controller's joint value (:func:`urdf_document`).

Numbers are written clean: values below 1e-12 as 0, 15 significant digits, unit axes, so that
every URDF reader computes the same forward kinematics (the tests check three independent ones).
Compliances, and what a URDF cannot hold (the robot's placement in the calibration's frame, the
calibration's tool), go to a sidecar YAML (:func:`compliance_document`).
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from ..core.errors import InputError
from ..core.outputs import output_dir, output_file, write_text
from ..core.se3 import inverse, rpy_from_rotation, so3_exp
from . import kinematics
from .ets import homogeneous
from .joints import OriginJoint
from .robot import Robot

TINY = 1e-12  # m or rad: below this a value is written as 0
# What fgcal's own layout writes where the robot file states nothing: URDF readers need non-zero
# joint speed and effort limits (MoveIt's time parameterisation divides by the speed, a simulator
# clamps the effort) and a positive definite inertia (Gazebo rejects zero).
PLACEHOLDER_VELOCITY = 1.0  # rad/s (m/s for a prismatic joint)
PLACEHOLDER_EFFORT = 1000.0  # N m (N)
INERTIA_DENSITY = 2700.0  # kg/m^3 (aluminium): a link's inertia is a solid sphere of its mass of this density


def number(value: float) -> str:
    """A value as URDF text: 0 below TINY, else 15 significant digits (no -0, no 1e-17 noise)."""
    value = float(value)
    return "0" if abs(value) < TINY else f"{value:.15g}"


def clean(value: float) -> float:
    """A value for YAML: 0 below TINY, else 15 significant digits (no 0.11999999999999922)."""
    return 0.0 if abs(value) < TINY else float(f"{value:.15g}")


def _vector(values) -> str:
    return " ".join(number(v) for v in values)


def _unit(axis: np.ndarray) -> np.ndarray:
    axis = np.where(np.abs(axis) < TINY, 0.0, axis)
    return axis / np.linalg.norm(axis)


def origin_attributes(T: np.ndarray) -> dict[str, str]:
    """``xyz`` and ``rpy`` of a pose, clean. Within TINY of gimbal lock the angles are taken at
    the lock exactly (yaw 0, roll carrying the turn), so that no reader divides by cos(pitch)."""
    roll, pitch, yaw = rpy_from_rotation(T[:3, :3])
    if abs(abs(pitch) - np.pi / 2) < TINY:
        pitch = np.copysign(np.pi / 2, pitch)
    return {"xyz": _vector(T[:3, 3]), "rpy": _vector((roll, pitch, yaw))}


def _origin_xml(T: np.ndarray) -> str:
    attributes = origin_attributes(T)
    return f'<origin xyz="{attributes["xyz"]}" rpy="{attributes["rpy"]}"/>'


def _comment(text: str) -> str:
    # "--" may not appear inside an XML comment.
    return "<!-- " + text.replace("--", "- -") + " -->"


def joint_frames(robot: Robot) -> dict:
    """Frames of the exported URDF in W at q = 0, at the robot's parameter values with the
    compliances zero: ``base`` (T_W_0), ``joints`` (n, 4, 4: joint i's frame, its motion's
    axis through the origin), ``axes`` (n, 3: in the joint frame, signed by the joint
    direction), ``origins`` (n, 4, 4: where each joint's URDF origin puts its frame: the joint
    frame, a coupled joint's offset undone, which its URDF value carries), ``bodies`` (n, 4, 4:
    the frames the link masses are given in), ``bends``
    (n, 4, 4: the bending frames), ``flange`` and ``tool``."""
    chain = robot.chain
    data = kinematics.forward(robot, robot.parameter_vector(), np.zeros((1, robot.n_joints)))
    frames = homogeneous(data.frames_rigid[:, 0])
    joints, origins, axes = [], [], []
    followers = {k for k, _, _ in robot.coupled}
    for i in range(robot.n_links):
        # The joint's motion ends right before its bending frame (a coupled joint's: one element
        # per joint it follows, all about one axis); at q = 0 the frame after it is B_i. A
        # coupled joint's URDF value is its own, sum c q + c_0: its axis is not signed.
        # (chain.carriers: before a deflection about the parent's axes, which comes before the row.)
        k = chain.carriers[i]
        sign = 1.0 if i in followers else robot.drives[i][0][0][1]
        # A joint given by its origin keeps its link frame (after the axis alignment is undone).
        J = frames[chain.link_end[i]] if isinstance(robot.joints[i], OriginJoint) else frames[k + 1]
        after_motion = frames[k + 1]
        if np.linalg.norm(J[:3, 3] - after_motion[:3, 3]) > 1e-12:
            raise ValueError(f"joint {i + 1}: the link frame is not on the joint axis")
        et = chain.elements[k]
        axis_world = sign * after_motion[:3, "xyz".index(et.axis[1])]
        axis = J[:3, :3].T @ axis_world
        back = np.eye(4)
        offset = robot.drives[i][1]
        if offset:  # a coupled joint's: in its URDF value (mimic offset), not in its origin
            if robot.joints[i].prismatic:
                back[:3, 3] = -offset * axis
            else:
                back[:3, :3] = so3_exp(-offset * axis)
        joints.append(J)
        origins.append(J @ back)
        axes.append(axis)
    return {
        "base": frames[chain.base_end],
        "joints": np.array(joints),
        "origins": np.array(origins),
        "axes": np.array(axes),
        "bodies": frames[list(chain.link_end)],
        "bends": frames[list(chain.bend)],
        "flange": frames[chain.flange],
        "tool": frames[chain.tool],
        "tips": {name: frames[index] for name, index in chain.tips},
    }


# -- a robot without a URDF of its own --------------------------------------------------------


def sphere_inertia(mass: float) -> float:
    """The principal moment (kg m^2) of a uniform solid sphere of ``mass`` at INERTIA_DENSITY about
    its centre, 2/5 m r^2: a stand-in where the robot file gives a mass and a centre of mass only."""
    radius = (3.0 * mass / (4.0 * np.pi * INERTIA_DENSITY)) ** (1.0 / 3.0)
    return 0.4 * mass * radius**2


def _link_xml(name: str, mass: float = 0.0, com: np.ndarray | None = None) -> str:
    if mass <= 0.0:
        return f"  <link name={quoteattr(name)}/>"
    inertia = number(sphere_inertia(mass))
    return (
        f"  <link name={quoteattr(name)}>\n"
        f'    <inertial>\n      <origin xyz="{_vector(com)}" rpy="0 0 0"/>\n      <mass value="{number(mass)}"/>\n'
        f'      <inertia ixx="{inertia}" ixy="0" ixz="0" iyy="{inertia}" iyz="0" izz="{inertia}"/>\n'
        "    </inertial>\n  </link>"
    )


def _fixed_xml(name: str, parent: str, child: str, T: np.ndarray) -> str:
    return (
        f'  <joint name={quoteattr(name)} type="fixed">\n'
        f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(child)}/>\n    {_origin_xml(T)}\n"
        "  </joint>"
    )


def urdf_document(robot: Robot, sidecar: str | None = None) -> str:
    """The URDF (text) of ``robot`` at its parameter values (a calibrated robot's estimates),
    with the ROS-Industrial link names."""
    f = joint_frames(robot)
    parts = [
        '<?xml version="1.0"?>',
        _comment(
            f"Written by fgcal from {robot.name}. Joint values are the controller's (rad, m); the calibrated "
            "geometry is folded into the joint origins and axes."
        ),
        _comment(
            "Inertias: each link's mass at its centre of mass as a uniform solid sphere of density "
            f"{INERTIA_DENSITY:g} kg/m^3 (aluminium; I = 2/5 m r^2 about each axis): a stand-in that keeps simulators "
            "stable, not identified. Joint limits (lower, upper) are the robot file's" + _ratings_note(robot)
        ),
    ]
    if sidecar:
        parts.append(_comment(f"Joint compliances (gravity deflection) cannot be expressed in URDF: see {sidecar}"))
    parts.append(f"<robot name={quoteattr(robot.name)}>")
    parts += [_link_xml("world"), _link_xml("base_link")]
    parts.append(_fixed_xml("world-base_link", "world", "base_link", f["base"]))

    def link_of(joint: int) -> tuple[str, np.ndarray]:
        return ("base_link", f["base"]) if joint < 0 else (f"link_{joint + 1}", f["joints"][joint])

    coupled = {k: sources for k, sources, _ in robot.coupled}
    masses = robot.masses * kinematics.body_scales(robot, robot.parameter_vector())[: robot.n_links]
    for i in range(robot.n_links):
        parent, T_parent = link_of(robot.parents[i] if robot.parents is not None else i - 1)
        link, J = link_of(i)
        com_in_joint = inverse(J) @ f["bodies"][i] @ np.append(robot.coms[i], 1.0)
        parts.append(_link_xml(link, float(masses[i]), com_in_joint[:3]))
        kind = "prismatic" if robot.joints[i].prismatic else "revolute"
        low, high = _joint_range(robot, i)
        velocity, effort = _rating(robot, i)
        follows = ""
        if i in coupled and len(coupled[i]) == 1:
            ((leader, c),) = coupled[i]
            offset = number(robot.drives[i][1])
            follows = f'\n    <mimic joint="joint_{leader + 1}" multiplier="{number(c)}" offset="{offset}"/>'
        elif i in coupled:  # URDF's mimic follows one joint
            terms = " ".join(f"{'-' if c < 0 else '+'}{number(abs(c))} joint_{s + 1}" for s, c in coupled[i])
            if robot.drives[i][1]:
                terms += f" {'-' if robot.drives[i][1] < 0 else '+'}{number(abs(robot.drives[i][1]))}"
            parts.append(_comment(f"joint_{i + 1} follows several joints: set its value to {terms}"))
        parts.append(
            f'  <joint name="joint_{i + 1}" type="{kind}">\n'
            f'    <parent link="{parent}"/>\n    <child link="{link}"/>\n'
            f"    {_origin_xml(inverse(T_parent) @ f['origins'][i])}\n"
            f'    <axis xyz="{_vector(_unit(f["axes"][i]))}"/>\n'
            f'    <limit lower="{number(low)}" upper="{number(high)}" effort="{number(effort)}" '
            f'velocity="{number(velocity)}"/>{follows}\n'
            "  </joint>"
        )
    tip_links = tip_link_names(robot)
    flange = tip_links[robot.flange_name] if is_tree(robot) else "flange"
    flange_parent, T_parent = link_of(robot.n_links - 1 if robot.flange_joint is None else robot.flange_joint)
    parts.append(_link_xml(flange, float(robot.payload_mass), robot.payload_com))
    parts.append(_fixed_xml(f"{flange_parent}-{flange}", flange_parent, flange, inverse(T_parent) @ f["flange"]))
    parts.append(_link_xml("tool0"))
    parts.append(_fixed_xml(f"{flange}-tool0", flange, "tool0", inverse(f["flange"]) @ f["tool"]))
    for name, joint, _ in robot.tips:  # a tree's other tips
        parent, T_parent = link_of(joint)
        parts.append(_link_xml(tip_links[name]))
        parts.append(
            _fixed_xml(f"{parent}-{tip_links[name]}", parent, tip_links[name], inverse(T_parent) @ f["tips"][name])
        )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def tip_link_names(robot: Robot) -> dict[str, str]:
    """The link of each tip in fgcal's layout: its name, unless that is a name of the layout
    (world, base_link, tool0, link_i), then ``NAME_tip`` (``NAME_tip2``, ...: never another
    link's name, so that no two links share one)."""
    layout = {"world", "base_link", "tool0", *(f"link_{i + 1}" for i in range(robot.n_links))}
    taken = layout | {name for name in robot.tip_names if name not in layout}
    out = {}
    for name in robot.tip_names:
        if name not in layout:
            out[name] = name
            continue
        link, k = f"{name}_tip", 2
        while link in taken:
            link, k = f"{name}_tip{k}", k + 1
        taken.add(link)
        out[name] = link
    return out


def _rating(robot: Robot, link: int) -> tuple[float, float]:
    """A joint's speed and effort limits: the robot file's, else the placeholders (a coupled joint's too)."""
    (first, *_), _ = robot.drives[link]
    stated = (np.nan, np.nan)
    if robot.ratings is not None and link not in {k for k, _, _ in robot.coupled}:
        stated = robot.ratings[first[0]]
    velocity = float(stated[0]) if np.isfinite(stated[0]) else PLACEHOLDER_VELOCITY
    effort = float(stated[1]) if np.isfinite(stated[1]) else PLACEHOLDER_EFFORT
    return velocity, effort


def _ratings_note(robot: Robot) -> str:
    """What the URDF comment says of the joints' effort and velocity limits."""
    stated = np.zeros((robot.n_links, 2), dtype=bool)
    if robot.ratings is not None:
        for i in range(robot.n_links):
            if i not in {k for k, _, _ in robot.coupled}:
                stated[i] = np.isfinite(robot.ratings[robot.drives[i][0][0][0]])
    placeholder = (
        f"PLACEHOLDERS ({PLACEHOLDER_EFFORT:g} N m or N, {PLACEHOLDER_VELOCITY:g} rad/s or m/s): the robot file "
        "states none, take your robot's from its data sheet"
    )
    if stated.all():
        return ", and so are effort and velocity."
    if not stated.any():
        return f"; effort and velocity are {placeholder}."
    missing = [f"joint_{i + 1} {kind}" for i in range(robot.n_links) for kind, ok in
               zip(("velocity", "effort"), stated[i], strict=True) if not ok]  # fmt: skip
    return f", and so are effort and velocity, but for {', '.join(missing)}: {placeholder}."


def _joint_range(robot: Robot, link: int) -> tuple[float, float]:
    """The URDF joint's range: the controller's limits, or for a coupled joint the range of
    sum c_i q_i + c_0 over its leaders' limits."""
    (first, *more), _ = robot.drives[link]
    if not more and link not in {k for k, _, _ in robot.coupled}:
        low, high = robot.limits[first[0]]
        return float(low), float(high)
    ends = [sorted((c * robot.limits[column, 0], c * robot.limits[column, 1])) for column, c in (first, *more)]
    offset = robot.drives[link][1]
    return float(sum(e[0] for e in ends) + offset), float(sum(e[1] for e in ends) + offset)


# -- a robot that came from a URDF -------------------------------------------------------------


def _moving_chain(template: Path, tip: str) -> tuple[list, str]:
    """The joints (fgcal.model.urdf_io's model) from the template's root to ``tip``, and its root link."""
    from .urdf_io import _chain_to, _parse

    model = _parse(template)
    root, _, chain = _chain_to(template, model, tip)
    return chain, root


SAME_ROBOT_M = 1e-9  # a template is the robot's URDF when its FK is the nominal model's to this (m, and rotation)
SAME_ROBOT_CONFIGURATIONS = 32  # seeded configurations within the limits at which the FK is compared


def _motion(joint, value: float) -> np.ndarray:
    axis = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
    T = np.eye(4)
    if joint.type == "prismatic":
        T[:3, 3] = value * axis
    else:
        T[:3, :3] = so3_exp(value * axis)
    return T


def _template_fk(chain: list, root: str, tip: str, q: np.ndarray) -> np.ndarray:
    """The tip link's pose in the root link's frame at joint values ``q`` (the chain's moving joints)."""
    placed, k = {root: np.eye(4)}, 0
    for joint in chain:
        T = placed[joint.parent] @ joint.origin
        if joint.type != "fixed":
            T = T @ _motion(joint, q[k])
            k += 1
        placed[joint.child] = T
    return placed[tip]


def _is_own_urdf(robot: Robot, template: Path, tip: str) -> bool:
    """The robot was read from this URDF: its joints are the template's (origins, axes, kinds)."""
    from .urdf_io import load_urdf

    nominal = load_urdf(template, tip)
    return (
        nominal.n_joints == robot.n_joints
        and all(
            isinstance(mine, OriginJoint)
            and mine.prismatic == theirs.prismatic
            and np.allclose(mine.origin, theirs.origin, atol=1e-9)
            and np.allclose(mine.axis, theirs.axis, atol=1e-9)
            for mine, theirs in zip(robot.joints, nominal.joints, strict=False)
        )
        and np.allclose(robot.flange_pose, nominal.flange_pose, atol=1e-9)
    )


def _body_offsets(robot: Robot, template: Path, tip: str, nominal: Robot | None) -> tuple[list, str, list]:
    """The template's chain, its root, and for each of its moving joints the template's link frame
    in fgcal's joint frame (``C_i``: constant, both frames on the same body).

    A robot read from this URDF: ``C_i`` is the identity. Any other (a DH robot and the vendor's
    URDF of it): ``nominal`` is the robot's nominal model, whose FK the template's must equal at
    seeded configurations within the limits (SAME_ROBOT_M); then ``C_i`` is read off both at the
    nominal values, and each joint's axis in the template must be fgcal's joint axis (the same line)."""
    chain, root = _moving_chain(template, tip)
    moving = [joint for joint in chain if joint.type != "fixed"]
    if _is_own_urdf(robot, template, tip):
        return chain, root, [np.eye(4)] * len(moving)
    refusal = f"is not the URDF {robot.name} was described by, nor a URDF of the same robot"
    if nominal is None:
        raise InputError(template, "joints", f"{refusal}: give the robot's nominal model (--nominal) to compare")
    if (
        len(moving) != robot.n_links
        or nominal.n_links != robot.n_links
        or any(type(a) is not type(b) for a, b in zip(robot.joints, nominal.joints, strict=False))
        or any(joint.mimic for joint in moving)
        or any((joint.type == "prismatic") != robot.joints[i].prismatic for i, joint in enumerate(moving))
    ):
        raise InputError(
            template, "joints", f"{refusal}: its chain to {tip} has {len(moving)} moving joints of other kinds "
            f"than {robot.name}'s {robot.n_links} (fgcal export writes the calibration into the robot's own URDF)",
        )  # fmt: skip
    from .rigid_fit import without_compliances

    rigid = without_compliances(nominal)
    fn = joint_frames(rigid)
    base = fn["base"]
    low = np.maximum(rigid.limits[:, 0], -np.pi)
    high = np.minimum(rigid.limits[:, 1], np.pi)
    q = np.random.default_rng(0).uniform(low, high, (SAME_ROBOT_CONFIGURATIONS, rigid.n_joints))
    q = np.vstack([np.zeros(rigid.n_joints), q])
    expected = inverse(base) @ rigid.fk(q)  # the flange in the base frame 0, which the template's root is
    got = np.array([_template_fk(chain, root, tip, row) for row in q])
    gap = np.abs(got - expected).max()
    if not gap <= SAME_ROBOT_M:
        raise InputError(
            template, "joints", f"{refusal}: its {tip} is up to {gap:.3g} (m, or in rotation) from {nominal.name}'s "
            f"flange over {len(q)} configurations (compared within {SAME_ROBOT_M:g}); its chain to {tip} has other "
            "joints (fgcal export writes the calibration into the robot's own URDF)",
        )  # fmt: skip
    offsets, placed, k = [], {root: np.eye(4)}, 0
    for joint in chain:
        placed[joint.child] = placed[joint.parent] @ joint.origin
        if joint.type == "fixed":
            continue
        C = inverse(inverse(base) @ fn["joints"][k]) @ placed[joint.child]
        axis = C[:3, :3].T @ fn["axes"][k]
        theirs = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
        off_line = C[:3, 3] - (C[:3, 3] @ fn["axes"][k]) * fn["axes"][k]
        if np.abs(axis - theirs).max() > SAME_ROBOT_M or (
            joint.type != "prismatic" and np.linalg.norm(off_line) > SAME_ROBOT_M
        ):
            raise InputError(template, f"joint {joint.name}", f"{refusal}: its axis is not joint {k + 1}'s")
        offsets.append(C)
        k += 1
    return chain, root, offsets


def faithful_document(robot: Robot, template: Path, tip: str, sidecar: str | None = None, nominal: Robot | None = None):
    """The lxml tree of ``template`` (the robot's own URDF, or a URDF of the same robot: the same
    FK as ``nominal``) with the calibrated origins of the moving joints between its root and
    ``tip``, and those joints' names; nothing else of the document changes, but where the
    calibration moved the flange off the last joint's axis, the origin of the first fixed joint
    after it. The root link is the robot's base frame 0; fixed joints keep their origins."""
    from lxml import etree

    from .urdf_io import read_document

    chain, root_link, offsets = _body_offsets(robot, template, tip, nominal)
    tree = read_document(template)
    f = joint_frames(robot)
    # Each moving joint's link frame, calibrated: the same body frame as in the template (C_i), on
    # the calibrated joint frame.
    links = [f["joints"][k] @ C for k, C in enumerate(offsets)]
    axes = [C[:3, :3].T @ f["axes"][k] for k, C in enumerate(offsets)]
    last = max(i for i, joint in enumerate(chain) if joint.type != "fixed")
    tail = chain[last + 1 :]
    F = np.eye(4)
    for joint in tail:
        F = F @ joint.origin
    # What the calibration moved the flange by, in the last link's frame: a turn about its axis or
    # a shift along it is the link's own (its zero); the rest goes into the first fixed joint after it.
    delta = inverse(links[-1]) @ f["flange"] @ inverse(F)
    flange_joint, flange_delta = None, None
    if np.abs(delta - np.eye(4)).max() > TINY:
        a = _unit(axes[-1])
        along = chain[last].type == "prismatic" or np.linalg.norm(np.cross(delta[:3, 3], a)) < TINY
        if np.abs(delta[:3, :3] @ a - a).max() < TINY and along:
            links[-1] = links[-1] @ delta
        elif tail:
            flange_joint, flange_delta = tail[0].name, delta
        else:
            raise InputError(template, tip, f"the calibrated flange is off joint {robot.n_links}'s axis, and no "
                             f"fixed joint after it can carry that: add one (a flange link) to the URDF")  # fmt: skip
    elements = {element.get("name"): element for element in tree.getroot().findall("joint")}
    placed = {root_link: f["base"]}  # W pose of each chain link in the new document
    moving = 0
    for joint in chain:
        parent = placed[joint.parent]
        if joint.type == "fixed":
            if joint.name == flange_joint:
                origin = flange_delta @ joint.origin
                element = elements[joint.name].find("origin")
                if element is None:
                    element = etree.SubElement(elements[joint.name], "origin")
                for key, text in origin_attributes(origin).items():
                    element.set(key, text)
                placed[joint.child] = parent @ origin
            else:
                placed[joint.child] = parent @ joint.origin
            continue
        L = links[moving]
        element = elements[joint.name]
        origin = element.find("origin")
        if origin is None:  # the default identity origin, now a calibrated one
            origin = etree.SubElement(element, "origin")
        for key, text in origin_attributes(inverse(parent) @ L).items():
            origin.set(key, text)
        theirs = np.asarray(joint.axis, dtype=float) / np.linalg.norm(joint.axis)
        if np.abs(_unit(axes[moving]) - theirs).max() > TINY:  # a calibrated axis (distortions)
            axis = element.find("axis")
            if axis is None:
                axis = etree.SubElement(element, "axis")
            axis.set("xyz", _vector(_unit(axes[moving])))
        placed[joint.child] = L
        moving += 1
    tip_pose = placed[tip]
    if not np.allclose(tip_pose, f["flange"], atol=1e-9):  # the fixed joints to the tip are the robot's flange
        raise ValueError(f"the exported chain misses the flange by {np.abs(tip_pose - f['flange']).max():.3g}")
    note = f"Calibrated by fgcal: the origins of the joints from {root_link} to {tip} carry the calibration"
    if flange_joint is not None:
        note += f"; the origin of {flange_joint}, the flange's tilt or shift off joint {robot.n_links}'s axis"
    note += "."
    if sidecar:
        note += f" Compliances and the robot's placement: {sidecar}"
    tree.getroot().addprevious(etree.Comment(" " + note.replace("--", "- -") + " "))
    return tree, [joint.name for joint in chain if joint.type != "fixed"]


def serialise(tree) -> str:
    from lxml import etree

    return etree.tostring(tree, xml_declaration=True, encoding="UTF-8").decode("utf-8") + "\n"


# -- the sidecar and the files -----------------------------------------------------------------


def compliance_document(robot: Robot, urdf_name: str, joint_names: list[str] | None = None) -> dict:
    """The sidecar of an exported URDF: the joint compliances (rad/(N m)) and what they mean,
    the URDF's root in the calibration's frame W and the calibration's tool on the flange."""
    values = robot.nominal_parameters()
    frames = joint_frames(robot)
    names = joint_names or [f"joint_{i + 1}" for i in range(robot.n_links)]
    coupled = {k: (sources, offset) for k, sources, offset in robot.coupled}
    drivers = dict(robot.compliance_coupling)
    joints = []
    for i in range(robot.n_links):
        B_in_joint = inverse(frames["joints"][i]) @ frames["bends"][i]
        entry = {
            "joint": names[i],
            "compliance_rad_per_Nm": [values[f"{axis}{i + 1}"] for axis in ("kx", "ky", "kz")],
            "bending_frame_rpy_rad": [clean(v) for v in rpy_from_rotation(B_in_joint[:3, :3])],
        }
        if i in robot.parent_axis:  # bent about its parent's axes, at the frame its row starts from
            entry["about"] = "parent"
            entry["bending_frame_xyz_m"] = [clean(v) for v in B_in_joint[:3, 3]]
        if i in drivers:  # deflected about its bending frame's z by kc times another joint's z moment
            entry["coupled_compliance"] = {"from": names[drivers[i]], "kc_rad_per_Nm": values[f"kc{i + 1}"]}
        if i in coupled:  # its URDF value is sum c q; the offset is in its origin
            sources, offset = coupled[i]
            entry["follows"] = {names[s]: float(c) for s, c in sources}
            entry["offset"] = clean(offset)  # rad or m, in the joint's URDF value
        elif robot.history:  # which a URDF cannot hold either (fgcal.model.motion)
            column = robot.drives[i][0][0][0]
            entry["lost_motion"] = clean(values[f"lm{column + 1}"])
            entry["speed_term"] = clean(values[f"lv{column + 1}"])
        joints.append(entry)

    def pose(T: np.ndarray) -> dict:
        return {"xyz_m": [clean(v) for v in T[:3, 3]], "rpy_rad": [clean(v) for v in rpy_from_rotation(T[:3, :3])]}

    return {
        "urdf": urdf_name,
        "robot": robot.name,
        "model": robot.model,
        "meaning": (
            "Joint i deflects by Rz(kz tz) Ry(ky ty) Rx(kx tx) right after its motion, in its bending frame B_i "
            "(bending_frame_rpy_rad: B_i in the URDF joint frame; z along the joint axis). t = (tx, ty, tz) is the "
            "gravity moment (N m) that joint i carries, in B_i: the weights of the links after it and of the payload "
            "(the URDF inertials, and loads) about B_i's origin, on the undeformed chain, with gravity "
            "gravity_m_per_s2 in world. A joint with about: parent bends before its motion instead, in the frame its "
            "row starts from (bending_frame_xyz_m, _rpy_rad in its joint frame at zero); coupled_compliance adds "
            "Rz(kc t_z) with the z moment of the joint it names."
        ),
        # Loads URDF has no place for: the tips' payloads and the fixed bodies (fgcal.model.robot).
        **(
            {"loads": [
                *({"tip": tip, "mass_kg": float(m), "com_m_in_tip": [float(v) for v in c]}
                  for tip, m, c in robot.tip_payloads),
                *({"body": name, "on": names[j] if j >= 0 else "base", "mass_kg": float(m),
                   "com_m_in_link": [float(v) for v in c]} for name, j, m, c in robot.fixed_bodies),
            ]}
            if robot.tip_payloads or robot.fixed_bodies
            else {}
        ),
        "gravity_m_per_s2": [float(v) for v in robot.gravity],
        "payload": {
            "mass_kg": float(robot.payload_mass),
            "com_m_in_flange": [float(v) for v in robot.payload_com],
            # fgcal's own layout carries it as the flange link's inertial; a robot's own URDF does not.
            "in_urdf": joint_names is None,
        },
        # fgcal's layout of a tree: each tip's link (its name, unless the layout has that name)
        **({"tip_links": tip_link_names(robot)} if joint_names is None and is_tree(robot) else {}),
        "base_in_world": pose(frames["base"]),
        "tool_in_flange": pose(inverse(frames["flange"]) @ frames["tool"]),
        "joints": joints,
        **(
            {
                "mass_scales": {name: float(values[f"mass.{name}"]) for name, _ in robot.mass_groups},
                "mass_scales_note": "the calibrated mass scales of the body groups, applied to the URDF's link masses",
            }
            if robot.mass_groups
            else {}
        ),
        **(
            {
                "motion_history": (
                    "Model DH,s,e,h: joint i is offset by lost_motion tanh(dq_i / 1 deg) + speed_term s dq_i / "
                    "max_j |dq_j| (rad; dq: its last move, s: the move's speed factor), which fgcal compensate "
                    "allows for (docs/model.md, Motion history)"
                )
            }
            if robot.history
            else {}
        ),
    }


def check_outputs(path: str | Path, field: str | None = None) -> tuple[Path, Path]:
    """The URDF's path and its sidecar's, both checked writable (before any work); ``field``: the
    option that named it."""
    path = Path(path)
    if path.suffix.lower() != ".urdf":
        raise InputError(path, field, "the URDF file name must end in .urdf")
    if path.is_dir():
        raise InputError(path, field, "is a folder: give the URDF file's name")
    output_dir(path.parent, field)
    output_file(path, field)
    sidecar = path.with_name(f"{path.stem}.compliance.yaml")
    output_file(sidecar)
    return path, sidecar


def export_urdf(
    robot: Robot,
    path: str | Path,
    template: str | Path | None = None,
    accuracy: dict | None = None,
    nominal: Robot | None = None,
) -> tuple[Path, Path]:
    """Write ``path`` (URDF) and its compliance sidecar beside it (``<stem>.compliance.yaml``,
    with ``accuracy``: what the URDF keeps, SI). A robot that came from a URDF (or
    ``template``, its URDF) is written into that document."""
    import yaml

    path, sidecar = check_outputs(path)  # both outputs checked before either is written
    source = None if is_tree(robot) else template_of(robot, template)
    if is_tree(robot) and template is not None:
        raise InputError(template, "--template", f"{robot.name} is a tree: it is written in fgcal's own layout")
    if source is None:
        text, names = urdf_document(robot, sidecar.name), None
    else:
        file, tip = source
        tree, names = faithful_document(robot, file, tip, sidecar.name, nominal)
        text = serialise(tree)
    write_text(path, text)
    document = compliance_document(robot, path.name, names)
    if accuracy:
        document["accuracy"] = accuracy
    write_text(sidecar, yaml.safe_dump(document, sort_keys=False))
    return path, sidecar


def is_tree(robot: Robot) -> bool:
    """A robot with branches, several tips or coupled joints: written in fgcal's own layout
    (links ``link_i``, each tip a link by its name), whatever URDF it came from."""
    return robot.parents is not None or bool(robot.tips) or bool(robot.coupled)


def template_of(robot: Robot, template: str | Path | None) -> tuple[Path, str] | None:
    """The URDF (file, tip) the export writes into: ``template``, else the robot's own."""
    if template is not None:
        tip = robot.urdf[1] if robot.urdf is not None else None
        from .urdf_io import _chain_to, _parse

        _, tip, _ = _chain_to(Path(template), _parse(Path(template)), tip)
        return Path(template), tip
    if robot.urdf is None:
        return None
    file = Path(robot.urdf[0])
    if not file.exists():
        raise InputError(
            None, "urdf", f"{robot.name} came from {file}, which is not there any more: give it with --template"
        )
    return file, robot.urdf[1]
