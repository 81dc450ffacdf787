"""The schema of a robot file (docs/formats.md, "Robot description"), and of what the files that
name a robot share: the ``robot:`` reference and a camera. The loader (robot_io.parse_robot)
validates a document here first; what depends on the robot itself (a tip's joint within the
chain, a coupling's joints, a calibrated region within the limits) it checks after."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from ..core.schema import Number, Pose, Schema, Units, checked, numbers, refuse, vector
from .robot import MODELS

LENGTH = "in the file's length unit (units.length, default m)"
ANGLE = "in the file's angle unit (units.angle, default rad)"


class UrdfFile(Schema):
    """A URDF's (or a xacro's) chain from its root to a named tip link."""

    file: str = Field(description="the URDF or xacro file, relative to this file")
    tip: str = Field(description="the link the chain ends at")


def _robot_reference(value: Any) -> Any:
    if isinstance(value, str):
        return value
    if isinstance(value, dict):
        for key in value:
            if key not in ("file", "tip"):
                raise refuse("unknown field (allowed: file, tip)", str(key))
        for key in ("file", "tip"):
            if key not in value:
                raise refuse("required field is missing", key)
            if not isinstance(value[key], str):
                raise refuse(f"expected a string, got {value[key]!r}", key)
        return value
    raise refuse(f"expected a bundled robot's name, a robot file or {{file: ARM.urdf, tip: LINK}}, got {value!r}")


RobotReference = checked(
    _robot_reference,
    lambda: {
        "description": "The robot: a bundled robot's name (abb_irb120), a robot file (YAML, URDF or xacro, relative "
        "to this file), or {file: ARM.urdf, tip: LINK} for a URDF's chain to a named link.",
        "anyOf": [{"type": "string"}, UrdfFile.model_json_schema()],
    },
)


class Intrinsics(Schema):
    """Pinhole intrinsics, in pixels."""

    fx: Number = Field(gt=0, description="focal length along u, px")
    fy: Number = Field(gt=0, description="focal length along v, px")
    cx: Number = Field(description="principal point u, px")
    cy: Number = Field(description="principal point v, px")


class Camera(Schema):
    """A camera: its image, intrinsics and distortion; ``mounting`` on the flange (a flange camera,
    the robot's tool) or none (a camera fixed in the cell)."""

    image_size: vector(2) = Field(description="width and height, px (positive integers)")
    intrinsics: Intrinsics
    distortion: vector(5) = Field([0.0] * 5, description="OpenCV's k1, k2, p1, p2, k3")
    mounting: Pose = Field(None, description=f"the camera's pose on the flange (T_n_C); xyz {LENGTH}, rpy {ANGLE}")


class Payload(Schema):
    mass: Number = Field(0.0, ge=0, description="kg")
    com: vector(3) = Field([0.0, 0.0, 0.0], description=f"centre of mass on the flange, {LENGTH}")


class Coupling(Schema):
    """A joint that follows others: q = sum(coefficient * q_source) + offset."""

    joints: list[int] = Field(description="the joints (1-based) this one follows, at least one")
    coefficients: numbers() = Field(description="one per joint followed")
    offset: Number = Field(0.0, description=f"{ANGLE} (a prismatic joint's: {LENGTH})")


class FixedFrame(Schema):
    """A constant transform between a joint's parent link and its row, calibrated through
    frame.{name}.tx .. rz."""

    name: str = Field(description="the frame's name (letters, digits and _): its parameters are frame.{name}.*")
    xyz: vector(3) = Field([0.0, 0.0, 0.0], description=LENGTH)
    rpy: vector(3) = Field([0.0, 0.0, 0.0], description=ANGLE)


class Compliance(Schema):
    """Where a joint's gravity deflection turns (model DH,s,e), and another joint's moment that drives it."""

    about: Literal["joint", "parent"] = Field(
        "joint", description="joint: about the axes after the joint's motion; parent: about the axes of the frame "
        "its row starts from (the parent link's), through that frame's origin"
    )  # fmt: skip
    coupled_from: int = Field(
        None, ge=1, description="the joint (1-based) whose moment about its z axis also turns this one about its "
        "z axis (parameter kc of this joint)"
    )  # fmt: skip


class TipPayload(Schema):
    """A load on a tip, both stated: a payload without its mass or centre of mass is a typing slip."""

    mass: Number = Field(ge=0, description="kg")
    com: vector(3) = Field(
        description=f"centre of mass in the tip's frame (moves with frame.TIP.* when calibrated), {LENGTH}"
    )


class Body(Schema):
    """A mass fixed to a joint's link (0: the base), such as a head on joints the controller does not move."""

    name: str
    joint: int = Field(ge=0, description="1-based joint whose link carries the body; 0 the base")
    mass: Number = Field(ge=0, description="kg")
    com: vector(3) = Field(description=f"centre of mass in that link's frame, {LENGTH}")


class Joint(Schema):
    """A joint: DH (theta, d, a, alpha; the robot's dh_convention or its own convention) or
    origin/axis/type, not both."""

    theta: Number = Field(None, description=f"DH joint offset, {ANGLE}")
    d: Number = Field(None, description=f"DH offset along z, {LENGTH}")
    a: Number = Field(None, description=f"DH length along x, {LENGTH}")
    alpha: Number = Field(None, description=f"DH twist, {ANGLE}")
    origin: Pose = Field(None, description=f"the joint's frame in its parent link's (URDF style); xyz {LENGTH}")
    axis: vector(3) = Field(None, description="the joint's axis in its frame (non-zero; default [0, 0, 1])")
    type: Literal["revolute", "prismatic"] = "revolute"
    convention: Literal["standard", "modified"] = Field(None, description="this DH joint's convention")
    parent: int = Field(None, ge=0, description="a tree: the joint (1-based) whose link this hangs from, 0 the base")
    coupling: Coupling = None
    direction: Number = Field(1.0, description="the sign (and ratio) of the joint's reading")
    limits: vector(2) = Field(None, description=f"[low, high], {ANGLE} (a prismatic joint's: {LENGTH})")
    velocity: Number = Field(None, gt=0, description="speed limit, the angle (or length) unit per second")
    effort: Number = Field(None, gt=0, description="effort limit, N m (a prismatic joint's: N)")
    mass: Number = Field(0.0, ge=0, description="the link's mass, kg")
    com: vector(3) = Field([0.0, 0.0, 0.0], description=f"the link's centre of mass in its frame, {LENGTH}")
    frame: FixedFrame = Field(None, description="a fixed frame between the parent link and this joint's row")
    compliance: Compliance = None


class Tip(Schema):
    """A named frame of a tree on a joint's link (0: the base)."""

    name: str
    joint: int = Field(ge=0, description="1-based joint whose link carries the tip; 0 the base")
    xyz: vector(3) = Field([0.0, 0.0, 0.0], description=LENGTH)
    rpy: vector(3) = Field([0.0, 0.0, 0.0], description=ANGLE)
    calibrate: bool = Field(False, description="the tip's pose has the six parameters frame.{name}.*")
    payload: TipPayload = Field(None, description="a load on the tip (a hand beyond an arm's last joint)")


class RobotFile(Schema):
    """A robot description (fgcal's YAML)."""

    name: str = Field(description="the robot's name (a valid XML name: it names the exported URDF)")
    source: str = Field(description="where the nominal values come from")
    model: Literal[MODELS] = Field("DH,s,e", description="the error model a calibration fits by default")
    dh_convention: Literal["standard", "modified"] = "standard"
    units: Units = None
    joints: list[Joint] = Field(description="the joints, base to flange")
    base: Pose = Field(None, description="the robot's base in the world frame W")
    flange: Pose = Field(None, description="the flange on the last link")
    tool: Pose = Field(None, description="the tool on the flange")
    payload: Payload = None
    gravity: vector(3) = Field([0.0, 0.0, -9.81], description="m/s^2 in the base frame")
    parameters: dict[str, Number] = Field(
        None, description=f"calibrated values by parameter name (lengths {LENGTH}, angles {ANGLE})"
    )
    urdf: UrdfFile = Field(None, description="the URDF this robot was read from (an export writes into it)")
    calibrated_region: list[numbers()] = Field(
        None, description="the configurations a calibration measured (joint units of the file)"
    )
    flange_joint: int = Field(None, ge=0, description="a tree: the joint (1-based) that carries the flange")
    flange_name: str = None
    tips: list[Tip] = None
    mass_groups: dict[str, list[int]] = Field(None, description="bodies whose masses one parameter scales")
    bodies: list[Body] = Field(None, description="masses fixed to a link (the gravity moments see them)")
    notes: Any = None
