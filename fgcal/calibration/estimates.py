"""Every estimate of a calibration besides the robot: ``estimates.yaml``.

calibrated_robot.yaml holds the robot; this file holds what else the calibration estimated,
each with its sigmas (SI: m, rad; poses as xyz and roll-pitch-yaw, sigmas of the tangent
perturbation [rotation, translation] of the pose's right side), so that fgcal and other tools
can read them back (docs/formats.md):

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

from ..fields import Fields, read_yaml
from ..se3 import inverse, pose_from_xyz_rpy, rpy_from_rotation
from .graph import (
    FIXED_POINTS_KEY,
    FIXTURE_KEY,
    INTRINSICS_KEY,
    OBJECT_KEY,
    TOOL_POINTS_KEY,
    TOOL_POSE_KEY,
    TRACKER_KEY,
)

FORMAT = "fgcal-estimates/1"
INTRINSICS = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3")


def _pose(T: np.ndarray) -> dict:
    return {"xyz": [float(v) + 0.0 for v in T[:3, 3]], "rpy": [float(v) + 0.0 for v in rpy_from_rotation(T[:3, :3])]}


def _sigmas(result, key: int) -> np.ndarray | None:
    joint = result.joint_covariance
    if joint is None or key not in joint.offsets:
        return None
    return np.sqrt(np.clip(np.diag(joint.block([key])), 0.0, None))


def _pose_sigma(sigma: np.ndarray | None) -> dict | None:
    if sigma is None:
        return None
    return {"rotation": [float(v) for v in sigma[:3]], "translation": [float(v) for v in sigma[3:]]}


def estimates_document(result) -> dict:
    """The estimates of a CalibrationResult as a YAML-ready document."""
    problem, state = result.problem, result.state
    robot = problem.robot
    params = robot.parameter_dict(state.params)
    zero = np.zeros((1, robot.n_joints))
    T_n_C = inverse(robot.fk(zero, params)[0]) @ robot.fk_tool(zero, params)[0]
    doc: dict = {"format": FORMAT, "units": {"length": "m", "angle": "rad"}, "camera_mounting": {"pose": _pose(T_n_C)}}
    formulation = problem.config.formulation
    if state.tracker_pose is not None:
        instrument = "static_camera" if formulation == "static_camera" else "tracker"
        doc[instrument] = {"pose": _pose(state.tracker_pose), "sigma": _pose_sigma(_sigmas(result, TRACKER_KEY))}
    if state.tool_pose is not None:
        doc["tool_frame"] = {"pose": _pose(state.tool_pose), "sigma": _pose_sigma(_sigmas(result, TOOL_POSE_KEY))}
    if state.tool_points is not None:
        names = {"tracker": problem.targets, "touch": ["probe"], "distances": ["ball"]}[formulation]
        doc["tool_points"] = _points(names, state.tool_points, _sigmas(result, TOOL_POINTS_KEY))
    if state.fixed_points is not None and len(state.fixed_points):
        key, names = (
            ("pivots", problem.pivots) if formulation == "distances" else ("touch_points", problem.touch_points)
        )
        doc[key] = _points(names, state.fixed_points, _sigmas(result, FIXED_POINTS_KEY))
    if state.fixture_pose is not None:
        doc["fixture"] = {"pose": _pose(state.fixture_pose), "sigma": _pose_sigma(_sigmas(result, OBJECT_KEY))}
    if state.fixture_rotation is not None:
        sigma = _sigmas(result, FIXTURE_KEY)
        doc["fixture_rotation"] = {
            "rpy": [float(v) for v in rpy_from_rotation(state.fixture_rotation)],
            "sigma": None if sigma is None else [float(v) for v in sigma],
        }
    if state.intrinsics is not None:
        sigma = _sigmas(result, INTRINSICS_KEY)
        doc["intrinsics"] = {name: float(v) for name, v in zip(INTRINSICS, state.intrinsics, strict=True)}
        doc["intrinsics"]["sigma"] = None if sigma is None else dict(zip(INTRINSICS, map(float, sigma), strict=True))
    return doc


def _points(names: list[str], points: np.ndarray, sigma: np.ndarray | None) -> dict:
    return {
        str(name): {
            "xyz": [float(v) for v in point],
            "sigma": None if sigma is None else [float(v) for v in sigma[3 * i : 3 * i + 3]],
        }
        for i, (name, point) in enumerate(zip(names, points, strict=True))
    }


def write_estimates(result, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(estimates_document(result), sort_keys=False), encoding="utf-8")


def load_estimates(path: str | Path) -> dict:
    """Read estimates.yaml back: 4x4 poses (T_n_C, T_T_W, T_W_F), tool points (name -> (3,)),
    the fixture rotation (3x3) and intrinsics (9,), whichever it holds; InputError on a
    damaged file."""
    path = Path(path)
    doc = Fields(read_yaml(path), path)
    doc.check_keys(("format", "units", "camera_mounting", "tracker", "static_camera", "tool_frame", "tool_points",
                    "touch_points", "pivots", "fixture", "fixture_rotation", "intrinsics"))  # fmt: skip
    if doc.string("format") != FORMAT:
        raise doc.error("format", f"expected {FORMAT!r}")
    out: dict = {}

    def pose(section: Fields) -> np.ndarray:
        inner = section.sub("pose")
        inner.check_keys(("xyz", "rpy"))
        return pose_from_xyz_rpy(inner.vector("xyz", 3), inner.vector("rpy", 3))

    out["camera_mounting"] = pose(doc.sub("camera_mounting"))
    for key, name in (("tracker", "tracker_pose"), ("static_camera", "tracker_pose"), ("tool_frame", "tool_pose")):
        if doc.has(key):
            out[name] = pose(doc.sub(key))
    for key in ("tool_points", "touch_points", "pivots"):
        if doc.has(key):
            points = doc.sub(key)
            out[key] = {str(name): points.sub(str(name)).vector("xyz", 3) for name in points.data}
    if doc.has("fixture"):
        out["fixture_pose"] = pose(doc.sub("fixture"))
    if doc.has("fixture_rotation"):
        out["fixture_rotation"] = pose_from_xyz_rpy(np.zeros(3), doc.sub("fixture_rotation").vector("rpy", 3))[:3, :3]
    if doc.has("intrinsics"):
        section = doc.sub("intrinsics")
        out["intrinsics"] = np.array([section.number(name) for name in INTRINSICS])
    return out
