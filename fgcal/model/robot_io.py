"""Robot description files (YAML) and the bundled robot library.

Schema (documented in docs/formats.md)::

    name: str                      # required
    source: str                    # where the numbers come from (required)
    units: {length: mm, angle: deg}   # of this file; default m, rad
    joints:                        # one entry per joint, base to flange
      - {theta: 0, d: 865, a: 410, alpha: -90, direction: -1, limits: [-185, 185],
         mass: 250, com: [x, y, z]}       # mass kg; com in the link's own frame
      - {origin: {xyz: [..], rpy: [..]}, axis: [0, 0, 1], type: revolute,   # or a joint as
         limits: [..], mass: .., com: [..]}  # URDF gives it (type revolute or prismatic)
    base: {xyz: [..], rpy: [..]}   # nominal T_W_0 (default identity)
    flange: {xyz: [..], rpy: [..]} # the flange in the last link's frame (default identity)
    tool: {xyz: [..], rpy: [..]}   # nominal T_n_C (default identity)
    payload: {mass: 0, com: [0, 0, 0]}   # kg; com in the flange frame
    gravity: [0, 0, -9.81]         # m/s^2 in W
    parameters: {sy3: 0.01, ...}   # optional values overriding nominal (a calibrated robot)
    urdf: {file: arm.urdf, tip: tool0}   # the URDF the joints came from (fgcal export keeps it)
    calibrated_region: [[q1, .., qn], ...]  # configurations a calibration was fitted on
"""

from __future__ import annotations

import os
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import InputError
from ..core.fields import Fields, check_name, read_file_text, read_yaml
from ..core.outputs import write_text
from ..core.schema import validate
from ..core.se3 import pose_from_xyz_rpy, rpy_from_rotation
from ..core.units import Units, parse_units
from . import kinematics
from .ets import homogeneous
from .joints import DHJoint, ModifiedDHJoint, OriginJoint
from .parameters import FRAME_LABEL, LENGTH_KINDS, MASS_KIND, is_motion, parameter_names, split_name
from .robot import MODELS, Robot
from .schema import RobotFile

DH_KEYS = ("theta", "d", "a", "alpha")
ORIGIN_KEYS = ("origin", "axis", "type")
CONVENTIONS = ("standard", "modified")
# DH: the SPEC's (standard) or Craig's (modified)
MAX_MOTION_TERM = float(np.radians(1.0))  # |lm|, |lv| in a robot file (SI)


def robots_dir() -> Path:
    """Folder of the bundled robot descriptions."""
    return Path(str(resources.files("fgcal.datasets").joinpath("robots")))


def bundled_robots() -> list[str]:
    return sorted(p.stem for p in robots_dir().iterdir() if p.suffix in (".yaml", ".urdf"))


def load_robot(name_or_path: str | Path, tip: str | None = None) -> Robot:
    """Load a bundled robot by name (e.g. ``"kuka_kr125_2"``), a robot YAML file or a URDF
    (the chain from its root link to ``tip``: default ``tool0``, else the only leaf)."""
    path = Path(name_or_path)
    if path.suffix.lower() not in ROBOT_FILE_SUFFIXES and (robots_dir() / f"{name_or_path}.urdf").exists():
        path = robots_dir() / f"{name_or_path}.urdf"  # a bundled URDF robot
    if path.suffix.lower() in URDF_SUFFIXES:  # a URDF, or a vendor's xacro expanded (fgcal.model.xacro_io)
        from .urdf_io import load_urdf

        return load_urdf(path, tip)
    if tip is not None:
        raise InputError(str(name_or_path), "tip", "a tip link applies to URDF files only")
    if path.suffix.lower() not in (".yaml", ".yml"):
        candidate = robots_dir() / f"{name_or_path}.yaml"
        if not candidate.exists():
            raise InputError(
                str(name_or_path), None, f"no such robot file or bundled robot (bundled: {', '.join(bundled_robots())})"
            )
        path = candidate
    return parse_robot(read_yaml(path), path)


URDF_SUFFIXES = (".urdf", ".xacro")
ROBOT_FILE_SUFFIXES = (".yaml", ".yml", *URDF_SUFFIXES)


def is_urdf_reference(name_or_path: str | Path) -> bool:
    """A URDF file, or a bundled robot given by a URDF (as load_robot resolves it)."""
    path = Path(name_or_path)
    if path.suffix.lower() in ROBOT_FILE_SUFFIXES:
        return path.suffix.lower() in URDF_SUFFIXES
    return (robots_dir() / f"{name_or_path}.urdf").exists()


def robot_reference(
    directory: Path, raw: object, source: str | Path | None = None, field: str = "robot", inside: Path | None = None
):
    """A ``robot:`` entry of a cell, dataset or mapping file, its robot file made absolute
    (relative to ``directory``): a bundled robot's name, a robot file (YAML or URDF), or
    ``{file: ARM.urdf, tip: LINK}`` for a URDF's chain to a named tip link. With ``inside``
    (a dataset's folder), a robot file must lie in that folder or the bundled library."""

    def resolved(file: str) -> str:
        path = (directory / file).resolve()
        library = path.is_relative_to(robots_dir().resolve())  # the bundled library may always be read
        if inside is not None and not path.is_relative_to(inside.resolve()) and not library:
            raise InputError(
                source, field, f"{file!r} is outside the dataset folder {inside}: a dataset's robot file is "
                "kept in the dataset (or name a bundled robot)",
            )  # fmt: skip
        return str(path)

    if isinstance(raw, str):
        return resolved(raw) if Path(raw).suffix.lower() in ROBOT_FILE_SUFFIXES else raw
    if isinstance(raw, dict):
        entry = Fields(raw, source or "<robot>", field)
        entry.check_keys(("file", "tip"))
        file = entry.string("file")
        if Path(file).suffix.lower() not in URDF_SUFFIXES:
            raise entry.error("file", f"a tip link names a link of a URDF (or xacro) file, got {file!r}")
        return {"file": resolved(file), "tip": entry.string("tip")}
    raise InputError(
        source, field, f"expected a bundled robot's name, a robot file or {{file: ARM.urdf, tip: LINK}}, got {raw!r}"
    )


def embed_robot(reference, out: Path):
    """The ``robot:`` entry of a dataset written to ``out`` for a resolved reference
    (robot_reference): a bundled name as it is; a robot file copied into the dataset (a
    dataset reads nothing outside its folder), as robot.yaml or robot.urdf."""
    file = reference["file"] if isinstance(reference, dict) else reference
    if not Path(file).is_absolute():  # a bundled robot's name
        return reference

    name = "robot" + Path(file).suffix.lower()
    target = out / name
    if Path(file).resolve() != target.resolve():
        write_text(target, read_file_text(file))
    return {**reference, "file": name} if isinstance(reference, dict) else name


def load_referenced(reference) -> Robot:
    """The robot a resolved ``robot:`` entry (robot_reference) names."""
    if isinstance(reference, dict):
        return load_robot(reference["file"], reference["tip"])
    return load_robot(reference)


def referenced_robot(fields: Fields, directory: Path, inside: Path | None = None) -> tuple[object, Robot]:
    """The ``robot:`` entry of a document (a dataset header, an import mapping) and the robot
    it names; a robot file is relative to ``directory`` (and in ``inside``, if given). Errors
    name the document's field."""
    raw = fields.raw("robot")
    reference = robot_reference(directory, raw, fields.source, fields.path("robot"), inside)
    try:
        return raw, load_referenced(reference)
    except InputError as exc:
        raise fields.error("robot", str(exc)) from None


def _pose(fields: Fields, key: str, units: Units) -> np.ndarray:
    if not fields.has(key):
        return np.eye(4)
    sub = fields.sub(key)
    return pose_from_xyz_rpy(sub.vector("xyz", 3, [0, 0, 0], units.to_m), sub.vector("rpy", 3, [0, 0, 0], units.to_rad))


def parameter_scale(name: str, units: Units) -> float:
    """Factor from a file's units to SI for one parameter (compliances: angle/(N m))."""
    kind, _ = split_name(name)
    if kind in LENGTH_KINDS:
        return units.to_m
    if kind == MASS_KIND:
        return 1.0
    return units.to_rad


def parse_robot(raw: object, source: str | Path) -> Robot:
    """Validate a robot document and build the :class:`Robot` (SI units)."""
    validate(raw, RobotFile, source)  # keys, types, nulls and choices; the checks below need the chain
    doc = Fields(raw, source)
    units = parse_units(doc.raw("units", None), source)
    name = _xml_name(doc.string("name"), source, "name")
    doc.string("source")
    convention = doc.string("dh_convention", "standard", CONVENTIONS)
    joints = doc.sub_list("joints")
    if not joints:
        raise doc.error("joints", "a robot needs at least one joint")
    geometries, directions, limits, masses, coms, parents, coupled, ratings = [], [], [], [], [], [], [], []
    fixed_frames, parent_axis, compliance_coupling = [], [], []
    for number, joint in enumerate(joints, start=1):
        if joint.has("frame"):
            fixed_frames.append(_fixed_frame(joint, number, units))
        about_parent, driver = _compliance(joint, number, len(joints))
        if about_parent:
            parent_axis.append(number - 1)
        if driver is not None:
            compliance_coupling.append((number - 1, driver))
        # A tree: the joint (1-based) whose link this one hangs from, 0 the base; default the one before.
        parents.append(joint.integer("parent", number - 1, minimum=0, maximum=number - 1) - 1)
        geometry = _joint_geometry(joint, units, convention)
        geometries.append(geometry)
        masses.append(joint.number("mass", 0.0, nonnegative=True))
        coms.append(joint.vector("com", 3, [0, 0, 0], units.to_m))
        if joint.has("coupling"):
            coupled.append(_coupling(joint, number, len(joints), units.to_m if geometry.prismatic else units.to_rad))
            continue
        direction = joint.number("direction", 1.0)
        if direction not in (1.0, -1.0):
            raise joint.error("direction", f"must be +1 or -1, got {direction}")
        directions.append(direction)
        lim = joint.vector("limits", 2, scale=units.to_m if geometry.prismatic else units.to_rad)
        if not lim[0] < lim[1]:
            raise joint.error("limits", "lower limit must be below upper limit")
        limits.append(lim)
        ratings.append(_ratings(joint, units.to_m if geometry.prismatic else units.to_rad))
    followers = {k for k, _, _ in coupled}
    for k, sources, _ in coupled:
        for leader, _ in sources:
            if leader in followers or leader == k:
                raise joints[k].error("coupling.joints", f"joint {leader + 1} is coupled itself: a coupled joint "
                                      "follows joints the controller moves")  # fmt: skip
            if geometries[leader].prismatic != geometries[k].prismatic:
                raise joints[k].error("coupling.joints", f"joint {leader + 1} is of another kind (revolute, "
                                      "prismatic): a coupled joint follows joints of its own kind")  # fmt: skip
    mass_groups = _mass_groups(doc, len(joints))
    tree = _tree(doc, units, parents)
    frame_names = [name for name, _, _ in fixed_frames] + list(tree["calibrated_tips"])
    for frame in frame_names:
        if frame_names.count(frame) > 1:
            where = next((f"joints[{j}].frame.name" for f, j, _ in reversed(fixed_frames) if f == frame), "tips")
            raise InputError(source, where, f"two fixed frames named {frame!r}: their parameters frame.{frame}.* clash")
    payload = doc.sub("payload", {})
    gravity = doc.vector("gravity", 3, [0.0, 0.0, -9.81])
    overrides = {}
    kc = {j for j, _ in compliance_coupling}
    names = set(
        parameter_names(
            [(*g.kinds, *(("kc",) if i in kc else ())) for i, g in enumerate(geometries)],
            len(directions), [g for g, _ in mass_groups], frame_names,
        )
    )  # fmt: skip
    params = doc.sub("parameters", {})
    for key in params.data:
        if key not in names:
            moved = f", {len(directions)} moved by the controller" if coupled else ""
            raise params.error(str(key), f"unknown parameter name for this {len(joints)}-joint robot{moved}")
        overrides[key] = params.number(key, scale=parameter_scale(key, units))
        if key.startswith(f"{MASS_KIND}.") and not overrides[key] > 0:
            raise params.error(key, f"a mass scale is a positive factor, got {overrides[key]!r}")
        if is_motion(key) and abs(overrides[key]) > MAX_MOTION_TERM:
            raise params.error(
                key, f"{overrides[key]:.3g} is beyond {MAX_MOTION_TERM:.3g} (1 deg or 17 mm): lost motion is "
                "hundredths of a degree",
            )  # fmt: skip
    robot = Robot(
        name=name,
        joints=tuple(geometries),
        directions=np.array(directions),
        limits=np.array(limits),
        masses=np.array(masses),
        coms=np.array(coms),
        payload_mass=payload.number("mass", 0.0, nonnegative=True),
        payload_com=payload.vector("com", 3, [0, 0, 0], units.to_m),
        gravity=gravity,
        base_pose=_pose(doc, "base", units),
        tool_pose=_pose(doc, "tool", units),
        flange_pose=_pose(doc, "flange", units),
        overrides=overrides,
        source=str(doc.raw("source")),
        model=doc.string("model", "DH,s,e", MODELS),
        urdf=_urdf_origin(doc, Path(source)),
        region=_region(
            doc, units, [g.prismatic for k, g in enumerate(geometries) if k not in followers], np.array(limits)
        ),
        coupled=tuple(coupled),
        mass_groups=mass_groups,
        ratings=np.array(ratings) if np.isfinite(ratings).any() else None,
        fixed_frames=tuple(fixed_frames),
        parent_axis=tuple(parent_axis),
        compliance_coupling=tuple(compliance_coupling),
        fixed_bodies=_fixed_bodies(doc, units, len(joints)),
        **tree,
    )
    _refuse_unparallel_coupling(robot, joints)
    return robot


COUPLED_AXES_DEG = 1.0  # a coupled compliance's joints: parallel within this at q = 0


def _refuse_unparallel_coupling(robot: Robot, joints: list[Fields]) -> None:
    """A coupled compliance kc_j deflects joint j by kc_j times joint i's moment about i's axis:
    the model of parallel joints on one branch (a pitch joint's torque bending the next). Between
    axes that are not parallel, or joints on different branches, it is no physical coupling, and a
    robot file stating one is refused rather than fitted."""
    if not robot.compliance_coupling:
        return
    parents = robot.parents if robot.parents is not None else tuple(range(-1, robot.n_links - 1))

    def ancestors(j: int) -> set[int]:
        out = set()
        while parents[j] >= 0:
            j = parents[j]
            out.add(j)
        return out

    # By design: the nominal geometry (a calibrated file's corrections tilt the axes a little).
    nominal = replace(robot, overrides={})
    chain = nominal.chain
    q = np.zeros((1, robot.n_joints))
    frames = homogeneous(kinematics.forward(nominal, nominal.parameter_vector(), q).frames_rigid[:, 0])

    def axis(i: int) -> np.ndarray:
        k = chain.carriers[i]
        return frames[k + 1][:3, "xyz".index(chain.elements[k].axis[1])]

    for j, i in robot.compliance_coupling:
        field = "compliance.coupled_from"
        if i not in ancestors(j) and j not in ancestors(i):
            raise joints[j].error(field, f"joint {i + 1} is on another branch than joint {j + 1}: a coupled "
                                  "compliance is between parallel joints of one branch")  # fmt: skip
        angle = np.degrees(np.arccos(np.clip(abs(float(axis(i) @ axis(j))), 0.0, 1.0)))
        if angle > COUPLED_AXES_DEG:
            raise joints[j].error(field, f"joint {i + 1}'s axis is {angle:.1f} deg from joint {j + 1}'s at q = 0: a "
                                  "coupled compliance is between parallel joints (a pitch joint's torque bending the "
                                  "next)")  # fmt: skip


MAX_RATING = 1e6  # rad/s, m/s, N m or N: beyond is a typo, not a robot


def _ratings(joint: Fields, to_si: float) -> tuple[float, float]:
    """``velocity`` (the file's angle or length unit per second) and ``effort`` (N m, or N for a
    prismatic joint) of a joint, SI; NaN where not stated."""
    out = []
    for key, scale in (("velocity", to_si), ("effort", 1.0)):
        if not joint.has(key):
            out.append(float("nan"))
            continue
        value = joint.number(key, positive=True)
        if not np.isfinite(value) or value > MAX_RATING:
            raise joint.error(key, f"must be finite, up to {MAX_RATING:g}, got {value!r}")
        out.append(value * scale)
    return out[0], out[1]


def _coupling(joint: Fields, number: int, n: int, to_si: float) -> tuple[int, tuple[tuple[int, float], ...], float]:
    """A coupled joint's ``coupling: {joints: [..], coefficients: [..], offset}``: its value is
    ``sum c_i q_i + offset`` of the joints (1-based) it follows; it has no direction or limits."""
    for key in ("direction", "limits", "velocity", "effort"):
        if joint.has(key):
            raise joint.error(key, f"a coupled joint follows others: its {key} is theirs")
    entry = joint.sub("coupling")
    sources = entry.items("joints")
    if not sources:
        raise entry.error("joints", "the joints (1-based) this one follows, at least one")
    for k, source in enumerate(sources):
        if isinstance(source, bool) or not isinstance(source, int) or not 1 <= source <= n:
            raise entry.error(f"joints[{k}]", f"another joint's number, 1 to {n}, got {source!r}")
        if source == number:
            raise entry.error(f"joints[{k}]", f"joint {number} cannot follow itself")
    if len(set(sources)) != len(sources):
        raise entry.error("joints", f"each joint once, got {sources}")
    coefficients = entry.vector("coefficients", len(sources))
    if np.any(coefficients == 0.0):
        raise entry.error("coefficients", "non-zero coefficients (a joint it does not follow is left out)")
    offset = entry.number("offset", 0.0, scale=to_si)
    return number - 1, tuple((s - 1, float(c)) for s, c in zip(sources, coefficients, strict=True)), offset


def _mass_groups(doc: Fields, n: int) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """``mass_groups: {name: [joints]}``: bodies (the links of the joints, 1-based) whose masses
    one parameter mass.{name} scales; each body in one group at most."""
    if not doc.has("mass_groups"):
        return ()
    groups = doc.sub("mass_groups")
    out, seen = [], set()
    for name in groups.data:
        if not isinstance(name, str) or not name.isidentifier():
            raise groups.error(str(name), "a group's name is a plain identifier (letters, digits, _)")
        members = groups.items(name)
        for k, member in enumerate(members):
            if isinstance(member, bool) or not isinstance(member, int) or not 1 <= member <= n:
                raise groups.error(f"{name}[{k}]", f"a joint's number, 1 to {n}, got {member!r}")
            if member in seen:
                raise groups.error(f"{name}[{k}]", f"joint {member}'s body is in another group already")
            seen.add(member)
        if not members:
            raise groups.error(name, "a group has at least one body")
        out.append((name, tuple(m - 1 for m in members)))
    return tuple(out)


def _tree(doc: Fields, units: Units, parents: list[int]) -> dict:
    """A tree's fields of Robot: joints' parents (None if serial), the flange's joint and name,
    the other tips ``[{name, joint, xyz, rpy}]`` (joint 1-based, 0 the base)."""
    n = len(parents)
    serial = all(p == i - 1 for i, p in enumerate(parents))
    out: dict = {"parents": None if serial else tuple(parents)}
    if doc.has("flange_joint"):
        out["flange_joint"] = doc.integer("flange_joint", n, minimum=0, maximum=n) - 1
    if doc.has("flange_name"):
        out["flange_name"] = _link_name(doc.string("flange_name"), doc.source, "flange_name")
    tips, calibrated, payloads = [], [], []
    for k, tip in enumerate(doc.sub_list("tips") if doc.has("tips") else []):
        name = _link_name(tip.string("name"), doc.source, f"tips[{k}].name")
        joint = tip.integer("joint", minimum=0, maximum=n) - 1
        pose = pose_from_xyz_rpy(
            tip.vector("xyz", 3, [0, 0, 0], units.to_m), tip.vector("rpy", 3, [0, 0, 0], units.to_rad)
        )
        tips.append((name, joint, pose))
        if tip.raw("calibrate", False) is True:
            if not FRAME_LABEL.match(name):
                raise tip.error("calibrate", f"a calibrated tip's parameters are frame.{name}.*: its name must be "
                                "letters, digits and _")  # fmt: skip
            calibrated.append(name)
        if tip.has("payload"):
            load = tip.sub("payload")
            payloads.append((name, load.number("mass", nonnegative=True), load.vector("com", 3, scale=units.to_m)))
    names = [name for name, _, _ in tips] + [out.get("flange_name", "flange")]
    if len(set(names)) != len(names):
        raise doc.error("tips", f"tip names must differ (and differ from the flange's): {names}")
    out["tips"] = tuple(tips)
    out["calibrated_tips"] = tuple(calibrated)
    out["tip_payloads"] = tuple(payloads)
    return out


def _fixed_frame(joint: Fields, number: int, units: Units) -> tuple[str, int, np.ndarray]:
    """A joint's ``frame: {name, xyz, rpy}``: a constant transform between its parent link and its
    row, calibrated through frame.{name}.*."""
    entry = joint.sub("frame")
    name = entry.string("name")
    if not FRAME_LABEL.match(name):
        raise entry.error("name", f"a fixed frame's parameters are frame.{name}.*: letters, digits and _, got {name!r}")
    pose = pose_from_xyz_rpy(entry.vector("xyz", 3, [0, 0, 0], units.to_m), entry.vector("rpy", 3, [0, 0, 0],
                                                                                            units.to_rad))  # fmt: skip
    return name, number - 1, pose


def _compliance(joint: Fields, number: int, n: int) -> tuple[bool, int | None]:
    """A joint's ``compliance: {about: joint | parent, coupled_from: i}``: whether it bends about its
    parent's axes, and the joint (0-based) whose z moment also deflects it (kc), if any."""
    if not joint.has("compliance"):
        return False, None
    entry = joint.sub("compliance")
    parent = entry.string("about", "joint", ("joint", "parent")) == "parent"
    if not entry.has("coupled_from"):
        return parent, None
    source = entry.integer("coupled_from", minimum=1, maximum=n)
    if source == number:
        raise entry.error("coupled_from", f"another joint's number: joint {number}'s own moment is its kz")
    return parent, source - 1


def _fixed_bodies(doc: Fields, units: Units, n: int) -> tuple[tuple[str, int, float, np.ndarray], ...]:
    """``bodies: [{name, joint, mass, com}]``: masses fixed to a joint's link (0: the base), with their
    centres of mass in that link's frame (a head on joints the controller does not move)."""
    out = []
    for k, body in enumerate(doc.sub_list("bodies") if doc.has("bodies") else []):
        name = _link_name(body.string("name"), doc.source, f"bodies[{k}].name")
        if name in [b[0] for b in out]:
            raise body.error("name", f"bodies' names must differ: {name!r} twice")
        out.append((name, body.integer("joint", minimum=0, maximum=n) - 1, body.number("mass", nonnegative=True),
                    body.vector("com", 3, scale=units.to_m)))  # fmt: skip
    return tuple(out)


def _link_name(text: str, source: str | Path, field: str) -> str:
    """A tip's name, which fgcal export writes as a URDF link's: printable, not empty or blank, and
    characters XML can hold (not U+FFFE, U+FFFF or a lone surrogate)."""
    if not text.strip():
        raise InputError(source, field, f"an empty name: a tip is a link of the exported URDF, {text!r}")
    return _xml_name(text, source, field)


def _xml_name(text: str, source: str | Path, field: str) -> str:
    """A name fgcal export writes into a URDF: printable, in characters XML can hold."""
    check_name(text, source, field)
    bad = next((c for c in text if 0xD800 <= ord(c) <= 0xDFFF or ord(c) in (0xFFFE, 0xFFFF)), None)
    if bad is not None:
        raise InputError(source, field, f"U+{ord(bad):04X} is no character XML (a URDF) can hold: {text!r}")
    return text


MAX_REGION = 10000  # configurations a robot file may list as its calibrated region


def _region(doc: Fields, units: Units, prismatic: list[bool], limits: np.ndarray) -> np.ndarray | None:
    """``calibrated_region``: configurations (joint units of the file), each with every joint."""
    if not doc.has("calibrated_region"):
        return None
    rows = doc.raw("calibrated_region")
    if not isinstance(rows, list) or not 0 < len(rows) <= MAX_REGION:
        raise doc.error("calibrated_region", f"a list of 1 to {MAX_REGION} configurations")
    scale = np.array([units.to_m if p else units.to_rad for p in prismatic])
    out = np.empty((len(rows), len(prismatic)))
    for k, row in enumerate(rows):
        ok = isinstance(row, list) and len(row) == len(prismatic)
        ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
        values = np.array(row, dtype=float) if ok else None
        if values is None or not np.all(np.isfinite(values)) or np.abs(values).max() > 1e3:
            raise doc.error(f"calibrated_region[{k}]", f"{len(prismatic)} finite joint values within 1000")
        out[k] = values * scale
        if np.any(out[k] < limits[:, 0] - 1e-6) or np.any(out[k] > limits[:, 1] + 1e-6):
            raise doc.error(f"calibrated_region[{k}]", "a configuration outside the joint limits")
    return out


def _urdf_origin(doc: Fields, source: Path) -> tuple[str, str] | None:
    """The ``urdf: {file, tip}`` entry: the URDF (relative to the robot file) its joints came from."""
    if not doc.has("urdf"):
        return None
    entry = doc.sub("urdf")
    file = entry.string("file")
    if Path(file).suffix.lower() not in URDF_SUFFIXES:
        raise entry.error("file", f"a URDF file's name ends in .urdf (a xacro's in .xacro), got {file!r}")
    return str((source.parent / file).resolve()), entry.string("tip")


def _joint_geometry(joint: Fields, units: Units, convention: str) -> DHJoint | ModifiedDHJoint | OriginJoint:
    """A DH joint (theta, d, a, alpha; in the robot's ``dh_convention`` or the joint's own
    ``convention``: standard or modified) or one given by origin, axis and type; not both."""
    dh_keys = [k for k in DH_KEYS if joint.has(k)]
    origin_keys = [k for k in ORIGIN_KEYS if joint.has(k)]
    if dh_keys and origin_keys:
        raise joint.error(origin_keys[0], f"a joint is DH ({', '.join(DH_KEYS)}) or origin/axis/type, not both")
    if origin_keys and joint.has("convention"):
        raise joint.error("convention", "a DH convention applies to DH joints, not to origin/axis/type")
    if not origin_keys:
        kind = ModifiedDHJoint if joint.string("convention", convention, CONVENTIONS) == "modified" else DHJoint
        return kind(
            joint.number("theta", 0.0, units.to_rad),
            joint.number("d", 0.0, units.to_m),
            joint.number("a", 0.0, units.to_m),
            joint.number("alpha", 0.0, units.to_rad),
        )
    kind = joint.raw("type", "revolute")  # revolute or prismatic: the schema's Joint.type
    axis = joint.vector("axis", 3, [0, 0, 1])
    if np.linalg.norm(axis) < 1e-9:
        raise joint.error("axis", "must be a non-zero vector")
    return OriginJoint(_pose(joint, "origin", units), axis, kind == "prismatic")


def _pose_dict(T: np.ndarray) -> dict:
    # "+ 0.0" turns -0.0 into 0.0 so that files read cleanly.
    return {"xyz": [float(v) + 0.0 for v in T[:3, 3]], "rpy": [float(v) + 0.0 for v in rpy_from_rotation(T[:3, :3])]}


def robot_document(robot: Robot, params: dict[str, float] | None = None, notes: str = "") -> dict:
    """A robot YAML document (SI units) for ``robot`` with parameter values ``params``.

    Joint DH fields carry the given theta/d/a/alpha; the remaining non-zero values go to
    ``parameters``. Loading the document reproduces ``robot.fk`` with ``params``.
    """
    values = robot.nominal_parameters()
    values.update(params or {})
    joints = []
    coupling = {k: (sources, offset) for k, sources, offset in robot.coupled}
    frames_before = {joint: (name, pose) for name, joint, pose in robot.fixed_frames}
    drivers = dict(robot.compliance_coupling)
    columns = iter(range(robot.n_joints))
    for i, geometry in enumerate(robot.joints, start=1):
        if isinstance(geometry, (DHJoint, ModifiedDHJoint)):
            entry = {kind: values.pop(f"{kind}{i}") for kind in DH_KEYS}
            if isinstance(geometry, ModifiedDHJoint):
                entry["convention"] = "modified"
        else:
            entry = {
                "origin": _pose_dict(geometry.origin),
                "axis": [float(v) for v in geometry.axis],
                "type": "prismatic" if geometry.prismatic else "revolute",
            }
        if robot.parents is not None:
            entry["parent"] = robot.parents[i - 1] + 1
        if i - 1 in coupling:
            sources, offset = coupling[i - 1]
            entry["coupling"] = {
                "joints": [s + 1 for s, _ in sources],
                "coefficients": [c for _, c in sources],
                "offset": offset,
            }
        else:
            column = next(columns)
            entry["direction"] = int(robot.directions[column])
            entry["limits"] = [float(v) for v in robot.limits[column]]
            if robot.ratings is not None:
                for key, value in zip(("velocity", "effort"), robot.ratings[column], strict=True):
                    if np.isfinite(value):
                        entry[key] = float(value)
        entry.update({"mass": float(robot.masses[i - 1]), "com": [float(v) for v in robot.coms[i - 1]]})
        if i - 1 in frames_before:
            name, pose = frames_before[i - 1]
            entry["frame"] = {"name": name, **_pose_dict(pose)}
        compliance = {}
        if i - 1 in robot.parent_axis:
            compliance["about"] = "parent"
        if i - 1 in drivers:
            compliance["coupled_from"] = drivers[i - 1] + 1
        if compliance:
            entry["compliance"] = compliance
        joints.append(entry)
    doc = {
        "name": robot.name,
        "source": robot.source,
        # The default model is not written: older readers take the file as it always was.
        **({"model": robot.model} if robot.model != "DH,s,e" else {}),
        "units": {"length": "m", "angle": "rad"},
        "joints": joints,
        "base": _pose_dict(robot.base_pose),
        "flange": _pose_dict(robot.flange_pose),
        "tool": _pose_dict(robot.tool_pose),
        "payload": {"mass": float(robot.payload_mass), "com": [float(v) for v in robot.payload_com]},
        "gravity": [float(v) for v in robot.gravity],
        "parameters": {k: float(v) for k, v in values.items() if v != 0.0},
    }
    if robot.urdf is not None:
        doc["urdf"] = {"file": robot.urdf[0], "tip": robot.urdf[1]}
    if robot.region is not None:
        doc["calibrated_region"] = [[float(v) for v in row] for row in robot.region]
    if robot.flange_joint is not None:
        doc["flange_joint"] = robot.flange_joint + 1
    if robot.flange_name != "flange":
        doc["flange_name"] = robot.flange_name
    if robot.mass_groups:
        doc["mass_groups"] = {name: [m + 1 for m in members] for name, members in robot.mass_groups}
    if robot.tips:
        loads = {tip: (mass, com) for tip, mass, com in robot.tip_payloads}
        doc["tips"] = []
        for name, joint, pose in robot.tips:
            tip = {"name": name, "joint": joint + 1, **_pose_dict(pose)}
            if name in robot.calibrated_tips:
                tip["calibrate"] = True
            if name in loads:
                tip["payload"] = {"mass": float(loads[name][0]), "com": [float(v) for v in loads[name][1]]}
            doc["tips"].append(tip)
    if robot.fixed_bodies:
        doc["bodies"] = [
            {"name": name, "joint": joint + 1, "mass": float(mass), "com": [float(v) for v in com]}
            for name, joint, mass, com in robot.fixed_bodies
        ]
    if notes:
        doc["notes"] = notes
    return doc


def save_robot(path: str | Path, robot: Robot, params: dict[str, float] | None = None, notes: str = "") -> None:
    doc = robot_document(robot, params, notes)
    if "urdf" in doc:  # relative to the robot file: a calibration folder moves with its dataset
        doc["urdf"]["file"] = os.path.relpath(doc["urdf"]["file"], Path(path).resolve().parent)
    write_text(path, yaml.safe_dump(doc, sort_keys=False))
