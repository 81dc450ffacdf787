"""The ground truth of a simulation, ``truth/ground_truth.yaml``: written by the simulator,
read only to score a finished calibration (fgcal.calibration.scoring), never by estimation.

SI throughout; poses as ``{xyz, rpy}`` in the file, 4x4 here::

    seed, cell, design, model            # the true robot is evaluated with this model
    parameters: {name: value}            # every parameter of the true robot
    camera_mounting_nominal, base_pose_nominal, fixture_pose: {xyz, rpy}
    tracker_pose: {xyz, rpy}             # T_W_T
    tracker_targets: {t1: [x, y, z]}     # reflectors, flange frame
    touch_probe: [x, y, z]               # flange frame;  touch_points: {name: [x, y, z]} in W
    tracker_probe: {xyz, rpy}            # T_n_E of a 6D probe
    ballbar: {ball: [3], pivots: {name: [3]}}
    static_camera: {pose: {xyz, rpy}, board_mount: {xyz, rpy}}   # T_W_C, T_n_B
    contact: {elements: {name: {xyz: [3], radius}}, planes: {name: {normal: [3], offset}}}  # tip frames; W
    self_observation: {cameras: {name: {xyz, rpy}}, boards: {name: {xyz, rpy}}}  # T_link_C, T_tip_B
    noise_sigma: {...}, deviation_before_calibration_m: {mean, max}, drift: {...}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from ..core.errors import InputError
from ..core.fields import Fields, read_yaml
from ..core.outputs import subfolder, write_text
from ..core.se3 import pose_from_xyz_rpy, rpy_from_rotation
from ..model.motion import MotionHistory

FILE = Path("truth") / "ground_truth.yaml"
NOTE = "Ground truth of a simulation: for scoring only; no estimation code reads this file."


@dataclass(frozen=True)
class Truth:
    seed: int
    cell: str
    design: str
    model: str
    parameters: dict[str, float]
    camera_mounting_nominal: np.ndarray
    base_pose_nominal: np.ndarray
    fixture_pose: np.ndarray
    tracker_pose: np.ndarray  # T_W_T
    tracker_targets: dict[str, np.ndarray]
    noise_sigma: dict[str, float]
    deviation_before_calibration_m: dict[str, float]
    touch_probe: np.ndarray | None = None
    touch_points: dict[str, np.ndarray] = field(default_factory=dict)
    tracker_probe: np.ndarray | None = None  # T_n_E
    ballbar_ball: np.ndarray | None = None
    ballbar_pivots: dict[str, np.ndarray] = field(default_factory=dict)
    static_camera_pose: np.ndarray | None = None  # T_W_C
    static_camera_board_mount: np.ndarray | None = None  # T_n_B
    drift: dict | None = None
    # Contact elements: name -> (centre on its tip (3,), radius); planes: name -> (unit normal in W, offset).
    contact_elements: dict[str, tuple[np.ndarray, float]] = field(default_factory=dict)
    contact_planes: dict[str, tuple[np.ndarray, float]] = field(default_factory=dict)
    # Self-observation: each camera's mounting on its link (T_link_C), each board's pose on its tip (T_tip_B).
    link_cameras: dict[str, np.ndarray] = field(default_factory=dict)
    tip_boards: dict[str, np.ndarray] = field(default_factory=dict)
    # How the simulator reached each configuration (fgcal.model.motion): id -> (joints before, rad or
    # m, NaN: unknown; speed factor). Scores against the truth use it, not the dataset's copy.
    motion_history: dict[str, tuple[np.ndarray, float]] | None = None

    def need(self, attribute: str, field: str) -> np.ndarray:
        """A part of the truth a score needs (``field``: its place in the file); a truth without
        it (damaged, or of another cell) is refused, naming the file and the field."""
        value = getattr(self, attribute)
        if value is None:
            raise InputError(FILE, field, f"the truth has no {field}, which a score of this dataset's measurements "
                             "needs: the file was edited, or comes from another cell's simulation")  # fmt: skip
        return value

    def history_of(self, config_ids, q: np.ndarray) -> MotionHistory | None:
        """The true history of these configurations (None: the truth has none, or does not
        know one of them)."""
        if self.motion_history is None or any(str(c) not in self.motion_history for c in config_ids):
            return None
        entries = [self.motion_history[str(c)] for c in config_ids]
        return MotionHistory(np.array([b for b, _ in entries], dtype=float).reshape(q.shape),
                             np.array([s for _, s in entries], dtype=float))  # fmt: skip

    def to_document(self) -> dict:
        doc: dict = {
            "note": NOTE,
            "seed": self.seed,
            "cell": self.cell,
            "design": self.design,
            "units": {"length": "m", "angle": "rad", "compliance": "rad/(N m)"},
            "model": self.model,
            "parameters": {k: float(v) for k, v in self.parameters.items()},
            "camera_mounting_nominal": _pose_doc(self.camera_mounting_nominal),
            "base_pose_nominal": _pose_doc(self.base_pose_nominal),
            "fixture_pose": _pose_doc(self.fixture_pose),
            "tracker_pose": _pose_doc(self.tracker_pose),
            "tracker_targets": _points_doc(self.tracker_targets),
        }
        if self.touch_probe is not None:
            doc["touch_probe"] = _vector(self.touch_probe)
            doc["touch_points"] = _points_doc(self.touch_points)
        if self.tracker_probe is not None:
            doc["tracker_probe"] = _pose_doc(self.tracker_probe)
        if self.ballbar_ball is not None:
            doc["ballbar"] = {"ball": _vector(self.ballbar_ball), "pivots": _points_doc(self.ballbar_pivots)}
        if self.static_camera_pose is not None:
            doc["static_camera"] = {
                "pose": _pose_doc(self.static_camera_pose),
                "board_mount": _pose_doc(self.static_camera_board_mount),
            }
        if self.contact_elements:
            doc["contact"] = {
                "elements": {n: {"xyz": _vector(c), "radius": float(r)} for n, (c, r) in self.contact_elements.items()},
                "planes": {n: {"normal": _vector(v), "offset": float(d)} for n, (v, d) in self.contact_planes.items()},
            }
        if self.link_cameras:
            doc["self_observation"] = {
                "cameras": {n: _pose_doc(T) for n, T in self.link_cameras.items()},
                "boards": {n: _pose_doc(T) for n, T in self.tip_boards.items()},
            }
        doc["noise_sigma"] = dict(self.noise_sigma)
        doc["deviation_before_calibration_m"] = dict(self.deviation_before_calibration_m)
        if self.drift is not None:
            doc["drift"] = dict(self.drift)
        if self.motion_history is not None:
            doc["motion_history"] = {
                cid: {"before": None if not np.all(np.isfinite(b)) else _vector(b), "speed": s}
                for cid, (b, s) in self.motion_history.items()
            }
        return doc

    def write(self, dataset_dir: str | Path) -> None:
        folder = subfolder(Path(dataset_dir), FILE.parent.name)
        write_text(folder / FILE.name, yaml.safe_dump(self.to_document(), sort_keys=False))


def load_truth(dataset_dir: str | Path) -> Truth | None:
    """The truth of a simulated dataset, or None when it has none (real data)."""
    path = Path(dataset_dir) / FILE
    if not path.exists():
        return None
    doc = Fields(read_yaml(path), path)
    parameters = doc.sub("parameters")
    optional = {}
    if doc.has("touch_probe"):
        optional["touch_probe"] = doc.vector("touch_probe", 3)
        optional["touch_points"] = _points(doc.sub("touch_points", {}))
    if doc.has("tracker_probe"):
        optional["tracker_probe"] = _pose(doc.sub("tracker_probe"))
    if doc.has("ballbar"):
        ballbar = doc.sub("ballbar")
        optional["ballbar_ball"] = ballbar.vector("ball", 3)
        optional["ballbar_pivots"] = _points(ballbar.sub("pivots", {}))
    if doc.has("static_camera"):
        camera = doc.sub("static_camera")
        optional["static_camera_pose"] = _pose(camera.sub("pose"))
        optional["static_camera_board_mount"] = _pose(camera.sub("board_mount"))
    if doc.has("contact"):
        contact = doc.sub("contact")
        elements, planes = contact.sub("elements", {}), contact.sub("planes", {})
        optional["contact_elements"] = {
            str(n): (elements.sub(str(n)).vector("xyz", 3), elements.sub(str(n)).number("radius"))
            for n in elements.data
        }
        optional["contact_planes"] = {
            str(n): (planes.sub(str(n)).vector("normal", 3), planes.sub(str(n)).number("offset")) for n in planes.data
        }
    if doc.has("self_observation"):
        seen = doc.sub("self_observation")
        cameras, boards = seen.sub("cameras", {}), seen.sub("boards", {})
        optional["link_cameras"] = {str(n): _pose(cameras.sub(str(n))) for n in cameras.data}
        optional["tip_boards"] = {str(n): _pose(boards.sub(str(n))) for n in boards.data}
    return Truth(
        seed=doc.integer("seed"),
        cell=doc.string("cell", ""),
        design=doc.string("design", ""),
        model=doc.string("model", "DH,s,e"),
        parameters={str(k): parameters.number(str(k)) for k in parameters.data},
        camera_mounting_nominal=_pose(doc.sub("camera_mounting_nominal")),
        base_pose_nominal=_pose(doc.sub("base_pose_nominal")),
        fixture_pose=_pose(doc.sub("fixture_pose")),
        tracker_pose=_pose(doc.sub("tracker_pose")),
        tracker_targets=_points(doc.sub("tracker_targets", {})),
        noise_sigma=dict(doc.raw("noise_sigma", {})),
        deviation_before_calibration_m=dict(doc.raw("deviation_before_calibration_m", {})),
        drift=doc.raw("drift", None),
        motion_history=_history(doc),
        **optional,
    )


def _history(doc: Fields) -> dict[str, tuple[np.ndarray, float]] | None:
    if not doc.has("motion_history"):
        return None
    out = {}
    for cid, entry in doc.sub("motion_history").data.items():
        before = entry.get("before")
        values = np.full(0, np.nan) if before is None else np.asarray(before, dtype=float)
        out[str(cid)] = (values, float(entry.get("speed", 1.0)))
    n = max((len(b) for b, _ in out.values()), default=0)
    return {cid: (b if len(b) else np.full(n, np.nan), s) for cid, (b, s) in out.items()}


def _pose_doc(T: np.ndarray) -> dict:
    # "+ 0.0" turns -0.0 into 0.0 so that files read cleanly.
    return {"xyz": _vector(T[:3, 3]), "rpy": _vector(rpy_from_rotation(T[:3, :3]))}


def _vector(v: np.ndarray) -> list[float]:
    return [float(x) + 0.0 for x in v]


def _points_doc(points: dict[str, np.ndarray]) -> dict:
    return {name: _vector(p) for name, p in points.items()}


def _pose(section: Fields) -> np.ndarray:
    return pose_from_xyz_rpy(section.vector("xyz", 3), section.vector("rpy", 3))


def _points(section: Fields) -> dict[str, np.ndarray]:
    return {str(name): section.vector(str(name), 3) for name in section.data}


def named_points(points: dict[str, np.ndarray], names, what: str) -> np.ndarray:
    """The true positions (K, 3) of ``names`` (points, targets, pivots) in the simulation's
    truth; a name the simulation never made (a renamed row) is the dataset's error."""
    missing = [name for name in names if name not in points]
    if missing:
        raise InputError(
            FILE, what, f"the dataset names {missing[0]!r}, which the simulation did not make ({', '.join(points)}): "
            "the tables were edited after fgcal simulate wrote them",
        )  # fmt: skip
    return np.array([points[name] for name in names])
