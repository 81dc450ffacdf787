"""Calibration configuration (YAML, documented in docs/calibration.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..fields import Fields, read_yaml
from ..parameters import JOINT_KINDS, ORIGIN_CORRECTION_KINDS
from ..robot import MODELS
from ..units import parse_units

FORMULATIONS = ("pairs", "tracker", "projection", "touch", "poses", "distances", "static_camera")
# Formulations whose data locate something on the flange (reflectors, a probe, a ballbar's ball,
# a board), not a camera on the tool.
FLANGE_FORMULATIONS = ("tracker", "touch", "poses", "distances", "static_camera")
KINDS = (*JOINT_KINDS, *ORIGIN_CORRECTION_KINDS, "base", "tool")
# Joints given by their origins (URDF) take their rotation corrections (rx, ry, rz) with the
# DH angles and their translation corrections (tx, ty, tz) with the lengths.
SEED_STAGES = (
    ("theta",),
    ("alpha", "sx", "sy", "rx", "ry", "rz"),
    ("kx", "ky", "kz"),
    ("theta", "alpha", "sx", "sy", "rx", "ry", "rz", "kx", "ky", "kz", "d", "a", "tx", "ty", "tz", "base", "tool"),
)
ONE_SHOT = (SEED_STAGES[-1],)
PARTNERS = ("other_object", "same_object", "same_side", "any")
CONFIG_KEYS = (
    "dataset",
    "units",
    "formulation",
    "model",
    "compliant_joints",
    "fixture_orientation",
    "schedule",
    "stages",
    "bounds",
    "noise",
    "robust",
    "pairs",
    "validation",
    "identifiability",
    "solver",
    "pixels_from",
    "intrinsics",
    "compare_models",
    "notes",
)


@dataclass(frozen=True)
class CalibrationConfig:
    path: Path
    dataset: Path
    formulation: str
    model: str
    compliant_joints: tuple[int, ...] | None  # None: default_compliant_joints of the robot
    fixture_orientation: str
    schedule: str
    stages: tuple[tuple[str, ...], ...]
    length_bound_m: float
    camera_point_sigma_m: float
    tracker_sigma_m: float
    pixel_sigma_px: float
    touch_sigma_m: float  # where a touch puts the tool point, about its socket
    spacing_sigma_m: float  # of the known distances between touch points
    pose_sigma_m: float  # of a measured pose's position (6D probe, a board's pose)
    pose_sigma_rad: float  # of a measured pose's orientation, about each axis
    distance_sigma_m: float  # of a ballbar's (1D gauge's) reading
    kinematic_sigma: float | None  # None: 1% of the measurement sigma
    robust: dict
    pair_partner: str
    group_images: int
    pair_points_from: str
    pair_seed: int
    holdout: float
    split_seed: int
    min_information: float
    max_iterations: int
    pixels_from: str = "table"
    # DH, DH,s and DH,s,e are all fitted and compared (always with model: auto).
    compare_models: bool = False
    solver_method: str = "lm"  # lm (fgcal's loop on GTSAM QR) | gtsam_lm (GTSAM's optimiser)
    # Camera intrinsics (projection): None = fixed at the dataset's values; otherwise the prior
    # sigmas (fx, fy, cx, cy in px; k1, k2, p1, p2, k3) around them, from an earlier calibration.
    intrinsics_prior_sigmas: tuple[float, ...] | None = None
    # A separate validation set (a dataset directory): its configurations are the held-out ones
    # (with the fitting set's own holdout, 0 by default then); tool points measured only there
    # are declared here (flange frame, m) or fitted leave-one-out.
    validation_dataset: Path | None = None
    validation_tool_points: dict = field(default_factory=dict)

    @property
    def measurement_sigma_m(self) -> float:
        """Measurement sigma in metres (pixels: at 1 m depth for a 1000 px focal length)."""
        return {
            "pairs": self.camera_point_sigma_m,
            "tracker": self.tracker_sigma_m,
            "projection": 1e-3 * self.pixel_sigma_px,
            "touch": self.touch_sigma_m,
            "poses": self.pose_sigma_m,
            "distances": self.distance_sigma_m,
            "static_camera": 1e-3 * self.pixel_sigma_px,
        }[self.formulation]

    @property
    def frame(self) -> str:
        """The frame the measurements locate: the flange (its points' positions are unknowns)
        or the tool (the camera)."""
        return "flange" if self.formulation in FLANGE_FORMULATIONS else "tool"

    @property
    def pose_tie_sigma(self) -> float:
        """Sigma of the kinematic factors (rad, m): the pose variables follow the kinematics
        a hundred times more tightly than the measurements constrain them, so they cannot
        absorb measurement residuals, yet Levenberg-Marquardt stays well conditioned."""
        return self.kinematic_sigma if self.kinematic_sigma is not None else 1e-2 * self.measurement_sigma_m

    @staticmethod
    def defaults(dataset: str | Path, **overrides) -> CalibrationConfig:
        """A configuration with every default, for the API and tests."""
        raw = {"dataset": str(dataset), **overrides}
        return parse_config(raw, Path("<defaults>"), base_dir=Path("."))


def _robust(fields: Fields, key: str, default):
    raw = fields.raw(key, default)
    if raw is None or raw == "none":
        return None
    if not (isinstance(raw, list) and len(raw) == 2 and raw[0] in ("huber", "cauchy")):
        raise fields.error(key, f"expected [huber|cauchy, threshold in sigmas] or none, got {raw!r}")
    threshold = Fields({"k": raw[1]}, fields.source, fields.path(key)).number("k", positive=True)
    return (str(raw[0]), threshold)


def _boolean(fields: Fields, key: str, default: bool) -> bool:
    value = fields.raw(key, default)
    if not isinstance(value, bool):
        raise fields.error(key, f"expected true or false, got {value!r}")
    return value


def _intrinsics(doc: Fields) -> tuple[float, ...] | None:
    """``intrinsics: {estimate: true, prior_sigma: {focal_px, centre_px, radial, tangential}}``."""
    section = doc.sub("intrinsics", {})
    section.check_keys(("estimate", "prior_sigma"))
    estimate = section.raw("estimate", False)
    if not isinstance(estimate, bool):
        raise section.error("estimate", f"expected true or false, got {estimate!r}")
    if not estimate:
        return None
    prior = section.sub("prior_sigma", {})
    prior.check_keys(("focal_px", "centre_px", "radial", "tangential"))
    focal = prior.number("focal_px", 5.0, positive=True)
    centre = prior.number("centre_px", 5.0, positive=True)
    radial = prior.number("radial", 0.01, positive=True)
    tangential = prior.number("tangential", 0.001, positive=True)
    return (focal, focal, centre, centre, radial, radial, tangential, tangential, radial)


def parse_config(raw: object, source: Path, base_dir: Path | None = None) -> CalibrationConfig:
    doc = Fields(raw, source)
    doc.check_keys(CONFIG_KEYS)
    units = parse_units(doc.raw("units", None), source)
    base = base_dir if base_dir is not None else source.parent
    formulation = doc.string("formulation", "pairs", FORMULATIONS)
    schedule = doc.string("schedule", "staged", ("staged", "one_shot", "custom"))
    if doc.has("stages"):
        schedule = "custom"
        stages = []
        for i, stage in enumerate(doc.items("stages")):
            if not isinstance(stage, list) or not stage:
                raise doc.error(f"stages[{i}]", "each stage is a non-empty list of parameter kinds")
            for kind in stage:
                if kind not in KINDS:
                    raise doc.error(f"stages[{i}]", f"unknown parameter kind {kind!r} (known: {', '.join(KINDS)})")
            stages.append(tuple(stage))
    elif schedule == "custom":
        raise doc.error("stages", "schedule 'custom' needs a stages list")
    else:
        stages = list(SEED_STAGES if schedule == "staged" else ONE_SHOT)
    # None: the seed's joints 1-3 that the robot has (resolved when the robot is known).
    joints = tuple(doc.items("compliant_joints")) if doc.has("compliant_joints") else None
    for j in joints or ():
        if isinstance(j, bool) or not isinstance(j, int) or j < 1:
            raise doc.error("compliant_joints", f"joint numbers are integers >= 1, got {j!r}")
    bounds = doc.sub("bounds", {})
    bounds.check_keys(("length",))
    noise = doc.sub("noise", {})
    noise.check_keys(
        (
            "camera_point_sigma",
            "tracker_sigma",
            "pixel_sigma_px",
            "touch_sigma",
            "spacing_sigma",
            "pose_sigma",
            "pose_angle_sigma",
            "distance_sigma",
            "kinematic_sigma",
        )
    )
    robust = doc.sub("robust", {})
    robust.check_keys(("camera_points", "tracker_points", "pixels", "touch_points", "tracker_poses", "distances"))
    pairs = doc.sub("pairs", {})
    pairs.check_keys(("partner", "seed", "group_images", "points_from"))
    validation = doc.sub("validation", {})
    validation.check_keys(("holdout", "seed", "dataset", "tool_points"))
    validation_dataset = base / validation.string("dataset") if validation.has("dataset") else None
    declared_points = validation.sub("tool_points", {})
    validation_tool_points = {
        str(name): tuple(declared_points.vector(str(name), 3, scale=units.to_m)) for name in declared_points.data
    }
    holdout = validation.number("holdout", 0.0 if validation_dataset is not None else 0.25)
    if not 0.0 <= holdout < 0.9:
        raise validation.error("holdout", f"fraction of configurations held out must be in [0, 0.9), got {holdout}")
    ident = doc.sub("identifiability", {})
    ident.check_keys(("min_information",))
    solver = doc.sub("solver", {})
    solver.check_keys(("max_iterations", "method"))
    to_m = units.to_m
    return CalibrationConfig(
        path=source,
        dataset=(base / doc.string("dataset")),
        formulation=formulation,
        model=doc.string("model", "DH,s,e", (*MODELS, "auto")),
        compare_models=_boolean(doc, "compare_models", False),
        compliant_joints=joints,
        fixture_orientation=doc.string("fixture_orientation", "known", ("known", "estimate")),
        schedule=schedule,
        stages=tuple(stages),
        length_bound_m=bounds.number("length", 0.01 / to_m, to_m, positive=True),
        camera_point_sigma_m=noise.number("camera_point_sigma", 1e-4 / to_m, to_m, positive=True),
        tracker_sigma_m=noise.number("tracker_sigma", 1e-5 / to_m, to_m, positive=True),
        pixel_sigma_px=noise.number("pixel_sigma_px", 0.1, positive=True),
        touch_sigma_m=noise.number("touch_sigma", 2e-5 / to_m, to_m, positive=True),
        spacing_sigma_m=noise.number("spacing_sigma", 1e-5 / to_m, to_m, positive=True),
        pose_sigma_m=noise.number("pose_sigma", 2e-5 / to_m, to_m, positive=True),
        pose_sigma_rad=noise.number("pose_angle_sigma", 1e-4 / units.to_rad, units.to_rad, positive=True),
        distance_sigma_m=noise.number("distance_sigma", 5e-6 / to_m, to_m, positive=True),
        kinematic_sigma=noise.number("kinematic_sigma", None, positive=True) if noise.has("kinematic_sigma") else None,
        robust={
            "camera_points": _robust(robust, "camera_points", None),
            "tracker_points": _robust(robust, "tracker_points", ["huber", 3.0]),
            "touch_points": _robust(robust, "touch_points", ["huber", 3.0]),
            "tracker_poses": _robust(robust, "tracker_poses", ["huber", 3.0]),
            "distances": _robust(robust, "distances", ["huber", 3.0]),
            # Cauchy: the influence of a gross false detection fades (Huber's stays k sigma).
            "pixels": _robust(robust, "pixels", ["cauchy", 3.0]),
        },
        pair_partner=pairs.string("partner", "other_object", PARTNERS),
        pair_seed=pairs.integer("seed", 0),
        group_images=pairs.integer("group_images", 4, minimum=1),
        pair_points_from=pairs.string("points_from", "camera_points", ("camera_points", "pixels")),
        holdout=holdout,
        split_seed=validation.integer("seed", 0),
        min_information=ident.number("min_information", 3.0, positive=True),
        max_iterations=solver.integer("max_iterations", 100, minimum=1),
        solver_method=solver.string("method", "lm", ("lm", "gtsam_lm")),
        pixels_from=doc.string("pixels_from", "table", ("table", "images")),
        intrinsics_prior_sigmas=_intrinsics(doc),
        validation_dataset=validation_dataset,
        validation_tool_points=validation_tool_points,
    )


def load_config(path: str | Path) -> CalibrationConfig:
    path = Path(path)
    return parse_config(read_yaml(path), path)
