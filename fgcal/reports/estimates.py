"""Every estimate of a calibration besides the robot: ``estimates.yaml``.

calibrated_robot.yaml holds the robot; this file holds the formulation's auxiliary unknowns,
each with its sigmas (SI: m, rad; poses as xyz and roll-pitch-yaw, sigmas of the tangent
perturbation [rotation, translation] of the pose's right side), so that fgcal and other tools
can read them back (docs/formats.md). One section per unknown, by its kind:

    format: fgcal-estimates/1
    units: {length: m, angle: rad}
    camera_mounting: {pose: {xyz, rpy}}                      # T_n_C, flange to camera (or tool)
    tracker: {pose: {xyz, rpy}, sigma: {rotation: [3], translation: [3]}}   # T_T_W
    static_camera: {pose: {xyz, rpy}, sigma: {...}}          # T_C_W, the eye-to-hand camera
    tool_frame: {pose: {xyz, rpy}, sigma: {...}}             # T_n_E, a 6D probe or a board on the flange
    tool_points: {t1: {xyz: [3], sigma: [3]}, ...}           # reflectors, a touch probe or a ball; flange
    touch_points: {p1: {xyz: [3], sigma: [3]}, ...}          # the touched fixed points, W
    pivots: {p1: {xyz: [3], sigma: [3]}, ...}                # a ballbar's fixed pivots, W
    fixture: {pose: {xyz, rpy}, sigma: {...}}                # T_W_F, projection formulation
    fixture_rotation: {rpy: [3], sigma: [3]}                 # R_W_F, pairs with an estimated one
    intrinsics: {fx_px, fy_px, cx_px, cy_px, k1, k2, p1, p2, k3, sigma: {...}}
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from ..calibration.results import CalibrationResult
from ..calibration.state import Auxiliary
from ..core.fields import Fields, read_yaml
from ..core.outputs import write_text
from ..core.se3 import inverse, pose_from_xyz_rpy, rpy_from_rotation

FORMAT = "fgcal-estimates/1"
# Section -> kind of what it holds; the sections a calibration writes are its unknowns' names.
SECTIONS = {
    "tracker": "pose3",
    "static_camera": "pose3",
    "tool_frame": "pose3",
    "fixture": "pose3",
    "fixture_rotation": "rot3",
    "tool_points": "points",
    "touch_points": "points",
    "pivots": "points",
    "intrinsics": "vector",
    "contact_centres": "points",
    "contact_radii": "vector",
    "contact_planes": "vector",
}
# Sections named by a prefix and a name of the dataset's (self-observation: each camera's mounting
# on its link, T_link_C, and each board's pose on its tip, T_tip_B): poses.
PREFIXED = ("mounting.", "board.")
INTRINSICS = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3")


def _floats(values) -> list[float]:
    return [float(v) + 0.0 for v in values]


def _pose(T: np.ndarray) -> dict:
    return {"xyz": _floats(T[:3, 3]), "rpy": _floats(rpy_from_rotation(T[:3, :3]))}


def _section(aux: Auxiliary, sigma: np.ndarray | None) -> dict:
    """One unknown with its sigmas (None when not estimated in the last stage)."""
    if aux.kind == "pose3":
        pose_sigma = None if sigma is None else {"rotation": _floats(sigma[:3]), "translation": _floats(sigma[3:])}
        return {"pose": _pose(aux.value), "sigma": pose_sigma}
    if aux.kind == "rot3":
        return {"rpy": _floats(rpy_from_rotation(aux.value)), "sigma": None if sigma is None else _floats(sigma)}
    if aux.kind == "points":
        return {
            str(name): {"xyz": _floats(point), "sigma": None if sigma is None else _floats(sigma[3 * i : 3 * i + 3])}
            for i, (name, point) in enumerate(zip(aux.labels, aux.value, strict=True))
        }
    out: dict = {name: float(v) for name, v in zip(aux.labels, aux.value, strict=True)}
    out["sigma"] = None if sigma is None else dict(zip(aux.labels, map(float, sigma), strict=True))
    return out


def estimates_document(result: CalibrationResult) -> dict:
    """The estimates of a CalibrationResult as a YAML-ready document."""
    robot, state = result.problem.robot, result.state
    params = robot.parameter_dict(state.params)
    zero = np.zeros((1, robot.n_joints))
    T_n_C = inverse(robot.fk(zero, params)[0]) @ robot.fk_tool(zero, params)[0]
    doc: dict = {"format": FORMAT, "units": {"length": "m", "angle": "rad"}, "camera_mounting": {"pose": _pose(T_n_C)}}
    for name, aux in state.aux.items():
        sigma = result.covariance.sigmas(name) if result.covariance is not None else None
        doc[name] = _section(aux, sigma)
    return doc


def write_estimates(result: CalibrationResult, path: str | Path) -> None:
    write_text(path, yaml.safe_dump(estimates_document(result), sort_keys=False))


def load_estimates(path: str | Path) -> dict:
    """Read estimates.yaml back, by section: 4x4 poses (camera_mounting T_n_C, tracker T_T_W,
    static_camera T_C_W, tool_frame T_n_E, fixture T_W_F), points (name -> (3,)), the fixture
    rotation (3x3) and the intrinsics (9,), whichever it holds; InputError on a damaged file."""
    path = Path(path)
    doc = Fields(read_yaml(path), path)
    # A calibration with several measurement sets names each set's unknowns SET/section; a
    # self-observation's are mounting.CAMERA and board.BOARD.
    sections = dict(SECTIONS)
    for key in map(str, doc.data):
        base = key.split("/", 1)[-1]
        if base in SECTIONS:
            sections[key] = SECTIONS[base]
        elif any(base.startswith(p) and len(base) > len(p) for p in PREFIXED):
            sections[key] = "pose3"
    doc.check_keys(("format", "units", "camera_mounting", *sections))
    if doc.string("format") != FORMAT:
        raise doc.error("format", f"expected {FORMAT!r}")

    def pose(section: Fields) -> np.ndarray:
        inner = section.sub("pose")
        inner.check_keys(("xyz", "rpy"))
        return pose_from_xyz_rpy(inner.vector("xyz", 3), inner.vector("rpy", 3))

    out: dict = {"camera_mounting": pose(doc.sub("camera_mounting"))}
    for key, kind in sections.items():
        if not doc.has(key):
            continue
        section = doc.sub(key)
        if kind == "pose3":
            out[key] = pose(section)
        elif kind == "rot3":
            out[key] = pose_from_xyz_rpy(np.zeros(3), section.vector("rpy", 3))[:3, :3]
        elif kind == "points":
            out[key] = {str(name): section.sub(str(name)).vector("xyz", 3) for name in section.data}
        elif key.split("/", 1)[-1] == "intrinsics":
            out[key] = np.array([section.number(name) for name in INTRINSICS])
        else:  # named entries, in the file's order
            out[key] = np.array([section.number(str(name)) for name in section.data if name != "sigma"])
    return out
