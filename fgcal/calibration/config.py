"""Calibration configuration (YAML, documented in docs/calibration.md): the pipeline's settings
here, the measurements' (noise, robust losses, formulation options) in .settings."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..core.fields import Fields, read_yaml
from ..core.noise import parse_noise
from ..core.schema import validate
from ..core.units import Units, parse_units
from ..data.dataset import MEASUREMENTS
from ..model.parameters import MASS_KIND
from ..model.robot import MODELS
from .formulations import NAMES, from_measured
from .priors import Priors, parse_priors
from .schema import CalibrationConfig as ConfigSchema
from .settings import MeasurementSettings, Noise, parse_intrinsics, parse_pairs, parse_robust

# Joints given by their origins (URDF) take their rotation corrections (rx, ry, rz) with the
# DH angles and their translation corrections (tx, ty, tz) with the lengths.
SEED_STAGES = (
    ("theta",),
    ("alpha", "sx", "sy", "rx", "ry", "rz"),
    ("kx", "ky", "kz", MASS_KIND),
    ("theta", "alpha", "sx", "sy", "rx", "ry", "rz", "kx", "ky", "kz", "d", "a", "tx", "ty", "tz", "base", "tool",
     "lm", "lv", MASS_KIND),
)  # fmt: skip
ONE_SHOT = (SEED_STAGES[-1],)


@dataclass(frozen=True)
class CalibrationConfig:
    path: Path
    dataset: Path
    formulation: str
    model: str
    compliant_joints: tuple[int, ...] | None  # None: default_compliant_joints of the robot
    schedule: str
    stages: tuple[tuple[str, ...], ...]
    priors: Priors
    measurement: MeasurementSettings
    holdout: float
    split_seed: int
    # Fit on the held-out part and hold out the fitting part: the split's other half, for
    # cross-validation on both halves of one split.
    complement: bool
    # "random": a seeded random split; "ordered": the last part of the run is held out (drift,
    # and what changes over a session, cannot hide in it).
    split: str
    min_information: float
    max_iterations: int
    pixels_from: str = "table"
    # Every model of MODELS is fitted and compared (always with model: auto).
    compare_models: bool = False
    # Separate validation sets (dataset directories): their configurations are held out (with
    # the fitting set's own holdout, 0 by default then).
    validation_datasets: tuple[Path, ...] = ()
    notes: dict = field(default_factory=dict)
    # "gp": a Gaussian process on what the kinematic model leaves (fgcal.calibration.residual_model)
    residual_model: str = "none"
    # The units the config's lengths and angles are read in, and where they came from: the
    # config's own ``units:``, else the dataset's (a config typed beside a dataset in mm is in mm),
    # else SI.
    units: Units = field(default_factory=Units)
    units_source: str = "SI: neither the config nor the dataset states units"
    formulation_source: str = "the config"

    @property
    def noise(self):
        return self.measurement.noise

    @staticmethod
    def defaults(dataset: str | Path, **overrides) -> CalibrationConfig:
        """A configuration with every default, for the API and tests."""
        raw = {"dataset": str(dataset), **overrides}
        return parse_config(raw, Path("<defaults>"), base_dir=Path("."))


def _stages(doc: Fields) -> tuple[str, tuple[tuple[str, ...], ...]]:
    schedule = doc.string("schedule", "staged", ("staged", "one_shot", "custom"))
    if not doc.has("stages"):
        if schedule == "custom":
            raise doc.error("stages", "schedule 'custom' needs a stages list")
        return schedule, SEED_STAGES if schedule == "staged" else ONE_SHOT
    return "custom", tuple(tuple(stage) for stage in doc.raw("stages"))  # their kinds: the schema's Stages


def _validation_datasets(validation: Fields, base: Path) -> tuple[Path, ...]:
    """``validation.dataset``: one directory, or a list of them (relative to the config)."""
    raw = validation.raw("dataset", None)
    if raw is None:
        return ()
    paths = tuple(base / e for e in (raw if isinstance(raw, list) else [raw]))
    if len({p.resolve() for p in paths}) != len(paths):
        raise validation.error("dataset", "a validation set is listed twice")
    return paths


def _dataset_header(dataset: Path) -> tuple[Path, dict]:
    """A dataset's header (empty when it cannot be read here: loading the dataset reports what
    is wrong with it)."""
    header = dataset / "dataset.yaml"
    doc = read_yaml(header) if header.is_file() else None
    return header, doc if isinstance(doc, dict) else {}


def _formulation(doc: Fields, header: Path, dataset: dict) -> tuple[str, str]:
    """The config's formulation, else the one that reads what the dataset measured; and where
    it came from, for the report."""
    if doc.has("formulation"):
        return doc.string("formulation", choices=NAMES), "the config"
    if not dataset:  # no header to ask (loading the dataset will say why): the seed's formulation
        return NAMES[0], "not given: the seed's default"
    measured = dataset.get("measured")
    camera = dataset.get("camera")
    on_flange = isinstance(camera, dict) and camera.get("mounting") is not None
    listed = measured if isinstance(measured, list) else []
    if not listed or any(kind not in MEASUREMENTS for kind in listed):  # loading names the bad field
        return NAMES[0], "not given: the seed's default"
    readers = from_measured(listed, on_flange)
    if not readers:
        raise doc.error(
            "formulation", f"not given, and {header} lists no measured table a formulation reads (measured: "
            f"{measured!r}); give one of {', '.join(NAMES)}",
        )  # fmt: skip
    others = f"; {', '.join(readers[1:])} would read it too" if len(readers) > 1 else ""
    return readers[0], f"not given: the dataset's measured tables ({', '.join(map(str, measured))}){others}"


def parse_config(raw: object, source: Path, base_dir: Path | None = None) -> CalibrationConfig:
    validate(raw, ConfigSchema, source)  # keys, types, nulls and choices; the checks below need the dataset
    doc = Fields(raw, source)
    base = base_dir if base_dir is not None else source.parent
    header, dataset_doc = _dataset_header(base / doc.string("dataset"))
    stated = parse_units(dataset_doc["units"], header) if dataset_doc.get("units") is not None else None
    if doc.has("units"):  # what it leaves out (units: {length: mm}) is the dataset's, as a whole one would be
        units = parse_units(doc.raw("units"), source, default=stated or Units())
        partial = stated and not {"length", "angle"} <= set(doc.raw("units") or {})
        units_source = "as the config's units: states" + (", the rest as the dataset's" if partial else "")
    else:
        units, units_source = (stated, "the dataset's units: the config states none") if stated else (
            Units(), "SI: neither the config nor the dataset states units"
        )  # fmt: skip
    formulation, formulation_source = _formulation(doc, header, dataset_doc)
    schedule, stages = _stages(doc)
    # None: the seed's joints 1-3 that the robot has (resolved when the robot is known).
    joints = tuple(doc.raw("compliant_joints")) if doc.has("compliant_joints") else None
    validation = doc.sub("validation", {})
    validation_datasets = _validation_datasets(validation, base)
    declared_points = validation.sub("tool_points", {})
    validation_tool_points = {
        str(name): tuple(declared_points.vector(str(name), 3, scale=units.to_m)) for name in declared_points.data
    }
    holdout = validation.number("holdout", 0.0 if validation_datasets else 0.25)  # in [0, 0.9): the schema
    ident = doc.sub("identifiability", {})
    solver = doc.sub("solver", {})
    stated = parse_noise(doc, units)
    measurement = MeasurementSettings(
        source=source,
        noise=Noise.stated(stated),
        noise_stated=stated,
        robust=parse_robust(doc),
        fixture_orientation=doc.string("fixture_orientation", "known", ("known", "estimate")),
        pairs=parse_pairs(doc),
        intrinsics_prior_sigmas=parse_intrinsics(doc),
        validation_tool_points=validation_tool_points,
    )
    return CalibrationConfig(
        path=source,
        dataset=(base / doc.string("dataset")),
        formulation=formulation,
        formulation_source=formulation_source,
        model=doc.string("model", "DH,s,e", (*MODELS, "auto")),
        compare_models=doc.raw("compare_models", False),
        compliant_joints=joints,
        schedule=schedule,
        stages=stages,
        priors=parse_priors(doc, units),
        measurement=measurement,
        holdout=holdout,
        split_seed=validation.integer("seed", 0, minimum=0, maximum=2**32 - 1),
        complement=validation.raw("complement", False),
        split=validation.string("split", "random", ("random", "ordered")),
        min_information=ident.number("min_information", 3.0, positive=True),
        max_iterations=solver.integer("max_iterations", 100, minimum=1),
        pixels_from=doc.string("pixels_from", "table", ("table", "images")),
        validation_datasets=validation_datasets,
        residual_model=doc.string("residual_model", "none", ("none", "gp")),
        units=units,
        units_source=units_source,
    )


def load_config(path: str | Path) -> CalibrationConfig:
    path = Path(path)
    return parse_config(read_yaml(path), path)
