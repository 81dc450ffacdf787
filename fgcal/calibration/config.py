"""Calibration configuration (YAML, documented in docs/calibration.md): the pipeline's settings
here, the measurements' (noise, robust losses, formulation options) in .settings."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import first_repeat, read_yaml, to_float
from ..core.noise import stated_noise
from ..core.schema import validate
from ..core.units import Units, parse_units
from ..data.dataset import MEASUREMENTS, line_numbers, read_csv
from ..model.parameters import MASS_KIND
from .formulations import NAMES, REGISTRY, from_measured
from .priors import Priors, parse_priors
from .schema import CalibrationConfig as ConfigSchema
from .schema import Identifiability, Pairs, PriorSigma, Robust, Solver, Validation
from .schema import Intrinsics as IntrinsicsSchema
from .settings import ROBUST_DEFAULTS, MeasurementSettings, Noise, PairSettings

# Joints given by their origins (URDF) take their rotation corrections (rx, ry, rz) with the
# DH angles and their translation corrections (tx, ty, tz) with the lengths.
SEED_STAGES = (
    ("theta",),
    ("alpha", "sx", "sy", "rx", "ry", "rz"),
    ("kx", "ky", "kz", "kc", MASS_KIND),
    ("theta", "alpha", "sx", "sy", "rx", "ry", "rz", "kx", "ky", "kz", "kc", "d", "a", "tx", "ty", "tz", "base",
     "tool", "frame", "lm", "lv", MASS_KIND),
)  # fmt: skip
ONE_SHOT = (SEED_STAGES[-1],)


@dataclass(frozen=True)
class SetConfig:
    """One measurement set of a config with several (``sets:``): its name, registered formulation,
    use (fit or validation), and what its formulation reads (noise, robust losses, options)."""

    name: str
    formulation: str
    use: str
    measurement: MeasurementSettings
    pixels_from: str = "table"
    stated_options: frozenset[str] = frozenset()


# The top-level fields a config with sets: states per set instead.
PER_SET = ("formulation", "noise", "robust", "pairs", "fixture_orientation", "pixels_from", "intrinsics")


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
    # The formulation-specific settings the config states (dotted: pairs, noise.tracker_sigma,
    # robust.pixels, ...): one the formulation does not read is said (reports.headline.warnings).
    stated_options: frozenset[str] = frozenset()
    # k-fold cross-validation (validation.folds): with ``fold`` that fold alone is held out; without,
    # the calibrate command runs every fold and the fit on all (calibration.cross_validation).
    folds: int | None = None
    fold: int | None = None
    # Several measurement sets (sets:); empty: the one formulation of the fields above.
    sets: tuple[SetConfig, ...] = ()

    @property
    def noise(self):
        return self.measurement.noise

    @staticmethod
    def defaults(dataset: str | Path, **overrides) -> CalibrationConfig:
        """A configuration with every default, for the API and tests."""
        raw = {"dataset": str(dataset), **overrides}
        return parse_config(raw, Path("<defaults>"), base_dir=Path("."))


def _stages(config: ConfigSchema, source: Path) -> tuple[str, tuple[tuple[str, ...], ...]]:
    if config.stages is None:
        if config.schedule == "custom":
            raise InputError(source, "stages", "schedule 'custom' needs a stages list")
        return config.schedule, SEED_STAGES if config.schedule == "staged" else ONE_SHOT
    stages = tuple(tuple(stage) for stage in config.stages)
    if "schedule" in config.model_fields_set and config.schedule != "custom":
        own = SEED_STAGES if config.schedule == "staged" else ONE_SHOT
        if stages != tuple(tuple(stage) for stage in own):  # a schedule the stages overrule: say which one runs
            steps = " then ".join("[" + ", ".join(stage) + "]" for stage in own)
            raise InputError(source, "schedule", f"{config.schedule!r} is the steps {steps}, and stages: lists others: "
                             "to run the stages, write schedule: custom (or leave schedule: out)")  # fmt: skip
    return "custom", stages


def _validation_datasets(raw: str | list[str] | None, base: Path, source: Path) -> tuple[Path, ...]:
    """``validation.dataset``: one directory, or a list of them (relative to the config)."""
    if raw is None:
        return ()
    paths = tuple(base / e for e in (raw if isinstance(raw, list) else [raw]))
    if len({p.resolve() for p in paths}) != len(paths):
        raise InputError(source, "validation.dataset", "a validation set is listed twice")
    return paths


def _dataset_header(dataset: Path) -> tuple[Path, dict]:
    """A dataset's header (empty when it cannot be read here: loading the dataset reports what
    is wrong with it)."""
    header = dataset / "dataset.yaml"
    doc = read_yaml(header) if header.is_file() else None
    return header, doc if isinstance(doc, dict) else {}


def _formulation(config: ConfigSchema, source: Path, header: Path, dataset: dict) -> tuple[str, str]:
    """The config's formulation, else the one that reads what the dataset measured; and where
    it came from, for the report."""
    if config.formulation is not None:
        return config.formulation, "the config"
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
        raise InputError(
            source, "formulation", f"not given, and {header} lists no measured table a formulation reads "
            f"(measured: {measured!r}); give one of {', '.join(NAMES)}",
        )  # fmt: skip
    others = f"; {', '.join(readers[1:])} would read it too" if len(readers) > 1 else ""
    return readers[0], f"not given: the dataset's measured tables ({', '.join(map(str, measured))}){others}"


def _robust(robust: Robust, source: Path, prefix: str = "") -> dict[str, tuple[str, float] | None]:
    """Each measurement kind's loss: (huber|cauchy, threshold in robust sigmas), or None (null or
    none: least squares)."""
    out = {}
    for key in ROBUST_DEFAULTS:
        loss = getattr(robust, key)
        off = loss is None or loss == "none"
        out[key] = None if off else (str(loss[0]), to_float(loss[1], source, f"{prefix}robust.{key}[1]"))
    return out


def _measurement(
    section, units: Units, source: Path, prefix: str = "", tool_points=None, base: Path = Path(".")
) -> tuple:
    """What a config (or one of its sets, ``prefix`` ``sets[i].``) says about its measurements:
    the MeasurementSettings and the formulation-specific options it states (dotted); ``base``:
    the folder its paths are relative to."""
    noise = stated_noise(section.noise.model_dump(exclude_unset=True) if section.noise else None, units, source,
                         f"{prefix}noise")  # fmt: skip
    pairs = section.pairs or Pairs()
    groups_file, groups, groups_lines = _pair_groups(pairs.groups, base, source, f"{prefix}pairs.groups")
    measurement = MeasurementSettings(
        source=source,
        noise=Noise.stated(noise),
        noise_stated=noise,
        robust=_robust(section.robust or Robust(), source, prefix),
        fixture_orientation=section.fixture_orientation,
        pairs=PairSettings(
            pairs.partner, pairs.seed, pairs.group_images, pairs.points_from, groups_file, groups, groups_lines
        ),
        intrinsics_prior_sigmas=_intrinsics(section.intrinsics),
        validation_tool_points=tool_points or {},
    )
    given = {key for key in ("pairs", "fixture_orientation", "intrinsics") if key in section.model_fields_set}
    given |= {"pairs.groups"} if pairs.groups is not None else set()
    given |= {f"noise.{key}" for key in (section.noise.model_fields_set if section.noise else ())}
    given |= {f"robust.{key}" for key in (section.robust.model_fields_set if section.robust else ())}
    return measurement, frozenset(given)


def _pair_groups(
    name: str | None, base: Path, source: Path, field: str
) -> tuple[Path | None, tuple[tuple[str, str], ...] | None, tuple[int, ...] | None]:
    """``pairs.groups``: the CSV (``config,group``, relative to the config) naming each
    configuration's pair group, its rows in the file's order and each one's line in the file;
    (None, None, None) without one.
    Which of its configurations the dataset has is checked where the dataset is read
    (formulations.pairs.pair_observations)."""
    if name is None:
        return None, None, None
    if "\x00" in name:  # pathlib refuses it with a ValueError
        raise InputError(source, field, f"a file name with a NUL character: {name!r}")
    path = base / name
    if not path.is_file():
        raise InputError(source, field, f"{path}: file not found (a CSV with columns config,group)")
    header, body = read_csv(path, ["config", "group"])
    if not body:
        raise InputError(path, None, f"no configurations: give each one's group (config,group; {field})")
    config, group = header.index("config"), header.index("group")
    rows = [(row[config].strip(), row[group].strip()) for row in body]
    lines = line_numbers(body)  # the file's own lines: fgcal plan's file starts with a comment
    for line, (cid, label) in zip(lines, rows, strict=True):
        if not cid or not label:
            raise InputError(path, f"line {line}, column {'group' if cid else 'config'}", "empty")
    repeat = first_repeat((line, cid) for line, (cid, _) in zip(lines, rows, strict=True))
    if repeat is not None:
        first, line, cid = repeat
        raise InputError(path, f"lines {first} and {line}, column config", f"{cid!r} given twice: one group each")
    return path, tuple(rows), lines


def _sets(
    config: ConfigSchema, units: Units, source: Path, dataset: dict, tool_points, base: Path = Path(".")
) -> tuple[SetConfig, ...]:
    """The config's measurement sets (sets:), checked: names unique, at least one fitting set,
    each one's table among the dataset's measured ones, its options ones its formulation reads."""
    if config.sets is None:
        return ()
    for key in PER_SET:
        if key in config.model_fields_set:
            raise InputError(source, key, f"a config with sets: states it per set (sets[i].{key})")
    measured = dataset.get("measured") if isinstance(dataset.get("measured"), list) else None
    out, names, tables = [], set(), {}
    for i, entry in enumerate(config.sets):
        where = f"sets[{i}]"
        if entry.name in names:
            raise InputError(source, f"{where}.name", f"{entry.name!r}: another set has this name")
        names.add(entry.name)
        formulation = REGISTRY[entry.formulation]
        if formulation.kind in tables:  # the same measurements twice would count twice
            raise InputError(source, f"{where}.formulation", f"{entry.formulation} reads {formulation.kind}, as "
                             f"sets[{tables[formulation.kind]}] does: each table is one set's")  # fmt: skip
        tables[formulation.kind] = i
        if measured is not None and entry.pixels_from == "table" and formulation.kind not in measured:
            raise InputError(source, f"{where}.formulation", f"{entry.formulation} reads {formulation.kind}, and the "
                             f"dataset measured {', '.join(map(str, measured)) or 'nothing'}")  # fmt: skip
        measurement, given = _measurement(entry, units, source, f"{where}.", tool_points, base)
        unread = sorted(given - set(formulation.settings_read) - {f"robust.{formulation.kind}"})
        if entry.pixels_from == "images" and "pixels_from" not in formulation.settings_read:
            unread.insert(0, "pixels_from")
        if unread:
            raise InputError(source, f"{where}.{unread[0]}", f"the {entry.formulation} formulation does not read it")
        out.append(SetConfig(entry.name, entry.formulation, entry.use, measurement, entry.pixels_from, given))
    if not any(s.use == "fit" for s in out):
        raise InputError(source, "sets", "no set is fitted (use: fit): validation sets score a calibration")
    return tuple(out)


def _intrinsics(intrinsics: IntrinsicsSchema | None) -> tuple[float, ...] | None:
    """``intrinsics: {estimate: true, prior_sigma: {focal_px, centre_px, radial, tangential}}``:
    the prior sigmas (fx, fy, cx, cy in px; k1, k2, p1, p2, k3), or None: fixed."""
    if intrinsics is None or not intrinsics.estimate:
        return None
    prior = intrinsics.prior_sigma or PriorSigma()
    focal, centre, radial, tangential = prior.focal_px, prior.centre_px, prior.radial, prior.tangential
    return (focal, focal, centre, centre, radial, radial, tangential, tangential, radial)


def parse_config(raw: object, source: Path, base_dir: Path | None = None) -> CalibrationConfig:
    """A calibration config from its YAML document: validated by its schema (keys, types, nulls,
    choices and bounds; its defaults are the schema's), then what needs the dataset."""
    config = validate(raw, ConfigSchema, source)
    base = base_dir if base_dir is not None else source.parent
    header, dataset_doc = _dataset_header(base / config.dataset)
    stated = parse_units(dataset_doc["units"], header) if dataset_doc.get("units") is not None else None
    if config.units is not None:  # what it leaves out (units: {length: mm}) is the dataset's, as a whole one would be
        units = parse_units(config.units, source, default=stated or Units())
        partial = stated and not {"length", "angle"} <= set(config.units)
        units_source = "as the config's units: states" + (", the rest as the dataset's" if partial else "")
    else:
        units, units_source = (stated, "the dataset's units: the config states none") if stated else (
            Units(), "SI: neither the config nor the dataset states units"
        )  # fmt: skip
    formulation, formulation_source = (None, "") if config.sets else _formulation(config, source, header, dataset_doc)
    schedule, stages = _stages(config, source)
    # None: the seed's joints 1-3 that the robot has (resolved when the robot is known).
    joints = tuple(config.compliant_joints) if config.compliant_joints is not None else None
    validation = config.validation or Validation()
    validation_datasets = _validation_datasets(validation.dataset, base, source)
    validation_tool_points = {
        str(name): tuple(np.array(xyz) * units.to_m) for name, xyz in (validation.tool_points or {}).items()
    }
    if validation.folds is not None:
        clash = next((key for key, given in (("holdout", validation.holdout is not None),
                                             ("complement", validation.complement),
                                             ("dataset", bool(validation_datasets))) if given), None)  # fmt: skip
        if clash is not None:
            raise InputError(source, f"validation.{clash}", "folds choose the held-out configurations themselves")
        if validation.fold is not None and validation.fold > validation.folds:
            raise InputError(source, "validation.fold", f"{validation.fold}: there are {validation.folds} folds")
    elif validation.fold is not None:
        raise InputError(source, "validation.fold", "a fold of what: give folds too")
    holdout = validation.holdout if validation.holdout is not None else (
        0.0 if validation_datasets or validation.folds else 0.25
    )  # fmt: skip
    measurement, given = _measurement(config, units, source, "", validation_tool_points, base)
    sets = _sets(config, units, source, dataset_doc, validation_tool_points, base)
    if sets:
        formulation, formulation_source = "sets", "the config's sets"
        measurement = sets[[s.use for s in sets].index("fit")].measurement
    return CalibrationConfig(
        sets=sets,
        stated_options=frozenset(given),
        path=source,
        dataset=(base / config.dataset),
        formulation=formulation,
        formulation_source=formulation_source,
        model=config.model,
        compare_models=config.compare_models,
        compliant_joints=joints,
        schedule=schedule,
        stages=stages,
        priors=parse_priors(config.bounds, units, source),
        measurement=measurement,
        holdout=holdout,
        split_seed=validation.seed,
        complement=validation.complement,
        split=validation.split,
        folds=validation.folds,
        fold=validation.fold,
        min_information=(config.identifiability or Identifiability()).min_information,
        max_iterations=(config.solver or Solver()).max_iterations,
        pixels_from=config.pixels_from,
        validation_datasets=validation_datasets,
        residual_model=config.residual_model,
        units=units,
        units_source=units_source,
    )


def load_config(path: str | Path) -> CalibrationConfig:
    path = Path(path)
    return parse_config(read_yaml(path), path)
