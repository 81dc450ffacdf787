"""The schema of a calibration config (docs/calibration.md); parse_config validates a config here
first, then reads its settings and checks what needs the dataset or the robot. Lengths and angles
in the config's units: its own ``units:``, else the dataset's, else SI."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import Field, create_model

from ..core.noise import NoiseSection
from ..core.schema import NUMBER_JSON, Number, Schema, Units, checked, refuse, to_number, vector
from ..model.parameters import COUPLED_COMPLIANCE, FRAME, JOINT_KINDS, MASS_KIND, MOTION_KINDS, ORIGIN_CORRECTION_KINDS
from ..model.robot import MODELS
from .formulations import NAMES
from .settings import PARTNERS, ROBUST_DEFAULTS

LENGTH = "the config's length unit"
ANGLE = "the config's angle unit"
LOSSES = ("huber", "cauchy")
LOSS = "[huber|cauchy, threshold in robust sigmas], or null or none: no robust loss (least squares)"
# The parameter kinds a stage may release.
KINDS = (*JOINT_KINDS, COUPLED_COMPLIANCE, *ORIGIN_CORRECTION_KINDS, *MOTION_KINDS, MASS_KIND, "base", "tool", FRAME)
NUMBER_POSITIVE = {"anyOf": [{**NUMBER_JSON["anyOf"][0], "exclusiveMinimum": 0}, *NUMBER_JSON["anyOf"][1:]]}


def _loss(value: Any) -> Any:
    if value is None or value == "none":
        return value
    if not (isinstance(value, list) and len(value) == 2 and value[0] in LOSSES):
        raise refuse(f"expected [huber|cauchy, threshold in sigmas] or none, got {value!r}")
    if not to_number(value[1], "[1]") > 0:
        raise refuse(f"must be > 0, got {value[1]!r}", "[1]")
    return value


Loss = checked(
    _loss,
    {
        "description": LOSS,
        "anyOf": [
            {"type": "array", "prefixItems": [{"enum": list(LOSSES)}, NUMBER_POSITIVE], "minItems": 2, "maxItems": 2},
            {"const": "none"},
            {"type": "null"},
        ],
    },
    nullable=True,
)
# The robust loss of each measurement kind (settings.ROBUST_DEFAULTS: the kinds and defaults).
Robust = create_model(
    "Robust",
    __base__=Schema,
    __doc__="The robust loss of each measurement kind, in robust sigmas (null or none: off, least squares).",
    **{
        key: (Loss, Field(list(default) if default else None, description=f"{LOSS}; default {default or 'none'}"))
        for key, default in ROBUST_DEFAULTS.items()
    },
)


class Pairs(Schema):
    """How the pairs formulation groups its images."""

    partner: Literal[PARTNERS] = "other_object"
    seed: int = Field(0, ge=0, le=2**32 - 1)
    group_images: int = Field(4, ge=1)
    points_from: Literal["camera_points", "pixels"] = "camera_points"
    groups: str = Field(
        None,
        min_length=1,
        description="a CSV (config,group), relative to the config: the group of each configuration's image, as "
        "fgcal plan writes it (pair_groups.csv); images it does not name are grouped at random",
    )


class PriorSigma(Schema):
    focal_px: Number = Field(5.0, gt=0)
    centre_px: Number = Field(5.0, gt=0)
    radial: Number = Field(0.01, gt=0)
    tangential: Number = Field(0.001, gt=0)


class Intrinsics(Schema):
    estimate: bool = Field(False, description="estimate the camera's intrinsics (with priors around the dataset's)")
    prior_sigma: PriorSigma = None


_PARAMETER = (
    r"^((theta|d|a|alpha|sx|sy|kx|ky|kz|kc|tx|ty|tz|rx|ry|rz|lm|lv)[1-9][0-9]*|(base|tool)\.(tx|ty|tz|rx|ry|rz)"
    r"|frame\.[A-Za-z_][A-Za-z0-9_]*\.(tx|ty|tz|rx|ry|rz)|mass\.[A-Za-z_][A-Za-z0-9_]*)$"
)
_JOINTS = r"^[1-9][0-9]*(-[1-9][0-9]*)?$"


def _joint_numbers(spec: Any, where: str) -> list[int]:
    """``[1-5, 8, "10-12"]`` -> the joints (1-based)."""
    if not isinstance(spec, list) or not spec:
        raise refuse("expected a non-empty list of joints (3, or a range 1-5)", where)
    out = []
    for item in spec:
        text = str(item) if isinstance(item, int) and not isinstance(item, bool) else item
        if not isinstance(text, str) or re.fullmatch(_JOINTS, text.replace(" ", "")) is None:
            raise refuse(f"{item!r} is not a joint (3) or a range of joints (1-5)", where)
        first, _, last = text.replace(" ", "").partition("-")
        low, high = int(first), int(last or first)
        if high < low:
            raise refuse(f"{item!r}: a range from low to high", where)
        out += list(range(low, high + 1))
    return out


def _release_items(items: Any, where: str) -> list[str]:
    """A stage's release list as strings: a kind (every joint's), a parameter's name, or
    ``{kind, joints}`` expanded to the names (alpha1..alpha5)."""
    if not isinstance(items, list) or not items:
        raise refuse("a non-empty list of parameter kinds, names or {kind, joints}", where)
    out = []
    for j, item in enumerate(items):
        here = f"{where}[{j}]"
        if isinstance(item, dict):
            if set(item) != {"kind", "joints"}:
                raise refuse("expected {kind: KIND, joints: [...]}", here)
            if item["kind"] not in JOINT_KINDS_OF_STAGES:
                kinds = ", ".join(JOINT_KINDS_OF_STAGES)
                raise refuse(f"{item['kind']!r} is not a kind of a joint's parameters ({kinds})", here)
            # "?name": released where the joint has that kind (a tree mixes DH rows and origin joints,
            # whose kinds differ); calibration.run checks the joints are the robot's.
            out += [f"?{item['kind']}{joint}" for joint in _joint_numbers(item["joints"], f"{here}.joints")]
        elif isinstance(item, str) and (item in KINDS or re.fullmatch(_PARAMETER, item)):
            out.append(item)
        else:
            kinds = ", ".join(KINDS)
            raise refuse(f"unknown parameter kind or name {item!r} (kinds: {kinds}; a name: d6, base.tz)", here)
    return out


def _stages(value: Any) -> Any:
    """Each stage: a list of kinds, parameter names and {kind, joints}, or {release: [...], fix:
    [names]}. Returned as lists of strings, a fixed parameter as "!name" (calibration.solve.selects)."""
    if not isinstance(value, list):
        raise refuse(f"expected a list, got {type(value).__name__}")
    if not value:
        raise refuse("at least one stage: with none, nothing is estimated")
    out = []
    for i, stage in enumerate(value):
        if isinstance(stage, dict):
            if not set(stage) <= {"release", "fix"} or "release" not in stage:
                raise refuse("expected {release: [...], fix: [parameter names]}", f"[{i}]")
            released = _release_items(stage["release"], f"[{i}].release")
            fixed = stage.get("fix") or []
            names = isinstance(fixed, list) and all(isinstance(n, str) and re.fullmatch(_PARAMETER, n) for n in fixed)
            if not names:
                raise refuse("a list of parameter names (d6, base.tz)", f"[{i}].fix")
            out.append(released + [f"!{name}" for name in fixed])
        else:
            out.append(_release_items(stage, f"[{i}]"))
    return out


JOINT_KINDS_OF_STAGES = (*JOINT_KINDS, *ORIGIN_CORRECTION_KINDS, *MOTION_KINDS, "kc")
_RELEASE_JSON = {"type": "array", "minItems": 1, "items": {"anyOf": [
    {"enum": list(KINDS)}, {"type": "string", "pattern": _PARAMETER},
    {"type": "object", "required": ["kind", "joints"], "additionalProperties": False, "properties": {
        "kind": {"enum": list(JOINT_KINDS_OF_STAGES)},
        "joints": {"type": "array", "minItems": 1, "items": {"anyOf": [
            {"type": "integer", "minimum": 1}, {"type": "string", "pattern": _JOINTS}]}}}}]}}  # fmt: skip


Stages = checked(
    _stages,
    {"type": "array", "minItems": 1, "items": {"anyOf": [
        _RELEASE_JSON,
        {"type": "object", "required": ["release"], "additionalProperties": False,
         "properties": {"release": _RELEASE_JSON, "fix": {"type": "array", "items": {"type": "string",
                                                                                    "pattern": _PARAMETER}}}}]},
     "description": "each stage: the parameter kinds it releases (every joint's), parameters by name (d6, "
     "base.tz), {kind, joints: [1-5, 8]}, or {release: [...], fix: [names]} (schedule custom; a list gives it)"},
)  # fmt: skip


def _datasets(value: Any) -> Any:
    entries = value if isinstance(value, list) else [value]
    if not entries or not all(isinstance(e, str) and e for e in entries):
        raise refuse(f"expected a dataset directory or a list of them, got {value!r}")
    return value


class Validation(Schema):
    """The held-out configurations the calibration is scored on."""

    holdout: Number = Field(None, ge=0, lt=0.9, description="fraction held out (default 0.25, 0 with a dataset)")
    seed: int = Field(0, ge=0, le=2**32 - 1)
    complement: bool = Field(False, description="fit on the held-out part and hold out the fitting part")
    split: Literal["random", "ordered"] = "random"
    dataset: checked(
        _datasets,
        {"description": "separate validation set(s): a dataset folder or a list, relative to the config",
         "anyOf": [{"type": "string", "minLength": 1}, {"type": "array", "items": {"type": "string", "minLength": 1},
                                                          "minItems": 1}]},
    ) = None  # fmt: skip
    tool_points: dict[str, vector(3)] = Field(None, description=f"points only a validation set measures, {LENGTH}")
    folds: int = Field(None, ge=2, le=50, description="k-fold cross-validation: each of k folds (seeded, or the "
                       "run's order with split: ordered) held out of a fit on the others, the errors pooled; the "
                       "calibration reported is the fit on all configurations")  # fmt: skip
    fold: int = Field(
        None, ge=1, description="with folds: run this fold alone (1-based), held out of a fit on the others"
    )


class Identifiability(Schema):
    min_information: Number = Field(3.0, gt=0)


class Solver(Schema):
    max_iterations: int = Field(100, ge=1)


def _bounds(value: Any) -> Any:
    if not isinstance(value, dict):
        raise refuse(f"expected a mapping, got {type(value).__name__}")
    for key, sigma in value.items():
        if sigma is None:
            raise refuse("is null: give a value", str(key))
        if not to_number(sigma, str(key)) > 0:
            raise refuse(f"must be > 0, got {sigma!r}", str(key))
    return value


class MeasurementSet(Schema):
    """One measurement set of a config with several (docs/calibration.md, "Several measurement
    sets"): a registered formulation with its own noise, robust losses and settings; the sets share
    the robot's parameters and keep their own auxiliary unknowns."""

    name: str = Field(
        pattern=r"^[A-Za-z][A-Za-z0-9_-]*$",
        description="the set's name: its report keys; its auxiliary unknowns are named NAME/unknown",
    )
    formulation: Literal[NAMES] = Field(description="a registered formulation")
    use: Literal["fit", "validation"] = Field(
        "fit",
        description="fit: in the calibration; validation: measured, "
        "never fitted, scored (its own unknowns registered on its fitting "
        "configurations with the robot held at the calibration)",
    )
    noise: NoiseSection = Field(None, description="the set's sigmas (win over the dataset's)")
    robust: Robust = None
    fixture_orientation: Literal["known", "estimate"] = "known"
    pairs: Pairs = None
    pixels_from: Literal["table", "images"] = "table"
    intrinsics: Intrinsics = None


class CalibrationConfig(Schema):
    """A calibration config (fgcal calibrate)."""

    dataset: str = Field(description="the dataset folder, relative to the config")
    units: Units = Field(None, description="the config's units (default the dataset's)")
    formulation: Literal[NAMES] = Field(None, description="default: the one that reads the dataset's measured tables")
    model: Literal[(*MODELS, "auto")] = Field("DH,s,e", description="the error model; auto: compare and pick")
    compliant_joints: list[Annotated[int, Field(ge=1)]] = Field(
        None,
        description="1-based joints with a compliance (default 1-3; on a tree every revolute joint carrying a mass)",
    )
    fixture_orientation: Literal["known", "estimate"] = "known"
    schedule: Literal["staged", "one_shot", "custom"] = "staged"
    stages: Stages = None
    bounds: checked(
        _bounds,
        {"type": "object", "additionalProperties": NUMBER_POSITIVE,
         "description": f"prior sigmas by class, kind or parameter name ({LENGTH}, {ANGLE})"},
    ) = None  # fmt: skip
    noise: NoiseSection = Field(None, description="the measurements' sigmas (win over the dataset's)")
    robust: Robust = None
    pairs: Pairs = None
    validation: Validation = None
    identifiability: Identifiability = None
    solver: Solver = None
    pixels_from: Literal["table", "images"] = "table"
    intrinsics: Intrinsics = None
    compare_models: bool = False
    residual_model: Literal["none", "gp"] = "none"
    sets: list[MeasurementSet] = Field(
        None,
        min_length=1,
        description="several measurement sets in one calibration, in place of formulation, "
        "noise, robust, pairs, fixture_orientation, pixels_from and intrinsics",
    )
    notes: Any = None
