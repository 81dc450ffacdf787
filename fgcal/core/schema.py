"""Typed schemas of the YAML files fgcal reads (pydantic models), and the one boundary that turns
a schema's refusal into the :class:`InputError` every loader raises (file, dotted field, one line).

Each file kind's model lives with the layer that owns the file (the calibration config's in
fgcal.calibration.schema, the robot's in fgcal.model.schema, ...); this module holds what they
share: the strict base model (unknown keys refused naming the key, null refused unless a field
documents it), numbers as fgcal reads them (finite, within MAX_MAGNITUDE, YAML 1.1's ``1e-4``
text taken as the number), fixed-length vectors, units and poses. ``json_schema`` publishes a
model as a JSON Schema (``fgcal schema KIND``), for an editor's YAML language server.

Null semantics (issue 38): null is a value. It means "none/off" only where a field's type
admits None (its description says what null means) and is refused elsewhere, a section too.
"""

from __future__ import annotations

import math
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Annotated, Any

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Discriminator,
    GetJsonSchemaHandler,
    Tag,
    ValidationError,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import PydanticCustomError, core_schema

from .errors import InputError
from .fields import MAX_MAGNITUDE, is_plain_number

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
# YAML 1.1 (PyYAML) reads 1e-4 (no dot) as text; fgcal takes such plain numbers as numbers.
PLAIN_NUMBER_PATTERN = r"^\s*[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]+)?\s*$"
NUMBER_JSON: dict = {
    "anyOf": [
        {"type": "number", "minimum": -MAX_MAGNITUDE, "maximum": MAX_MAGNITUDE},
        {"type": "string", "pattern": PLAIN_NUMBER_PATTERN, "description": "a number YAML 1.1 reads as text (1e-4)"},
    ]
}


def refuse(message: str, at: str = "") -> PydanticCustomError:
    """A refusal with fgcal's message; ``at`` extends the field's path (``[2]``, ``key``)."""
    return PydanticCustomError("fgcal", "{message}", {"message": message, "at": at})


class Schema(BaseModel):
    """A mapping of a file fgcal reads: strict types, unknown keys refused, null refused unless
    the field's type admits None (documented null)."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, protected_namespaces=())

    @model_validator(mode="before")
    @classmethod
    def _keys_and_nulls(cls, data: Any) -> Any:
        if not isinstance(data, Mapping):
            raise refuse(f"expected a mapping, got {type(data).__name__}")
        allowed = list(cls.model_fields)
        for key in data:
            if key not in allowed:
                raise refuse(f"unknown field (allowed: {', '.join(allowed)})", str(key))
        for key, value in data.items():
            field = cls.model_fields[key]
            if value is None and not admits_none(field.annotation):
                hint = "give a value" if field.is_required() else "give a value, or leave the field out for its default"
                raise refuse(f"is null: {hint}", str(key))
        return data


def admits_none(annotation: Any) -> bool:
    if annotation is None or annotation is type(None) or annotation is Any:  # Any: free (notes)
        return True
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        return admits_none(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return any(admits_none(arg) for arg in typing.get_args(annotation))
    return False


class _Json:
    """Metadata that sets a type's JSON Schema (constraints a field adds are kept beside it)."""

    def __init__(self, schema: dict | Callable[[], dict]) -> None:
        self.schema = schema

    def __get_pydantic_json_schema__(
        self, core: core_schema.CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        base = dict(self.schema() if callable(self.schema) else self.schema)
        constraints = {k: v for k, v in handler(core).items() if k not in ("type", "items", "anyOf", "allOf")}
        if constraints and "anyOf" in base:  # a bound applies to the number, not to its text form
            base["anyOf"] = [{**base["anyOf"][0], **constraints}, *base["anyOf"][1:]]
        else:
            base.update(constraints)
        return base


def to_number(value: Any, at: str = "") -> float:
    """A finite float within MAX_MAGNITUDE (fgcal.core.fields.to_float's rule), or a refusal."""
    if isinstance(value, str) and is_plain_number(value.strip()):
        value = float(value.strip())
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise refuse(f"expected a number, got {value!r}", at)
    number = float(value)
    if not math.isfinite(number):
        raise refuse(f"must be finite, got {value!r}", at)
    if abs(number) > MAX_MAGNITUDE:
        raise refuse(f"implausible value {value!r} (beyond {MAX_MAGNITUDE:g})", at)
    return number


Number = Annotated[float, BeforeValidator(to_number), _Json(NUMBER_JSON)]


def vector(length: int, what: str = "numbers") -> Any:
    """A list of ``length`` numbers."""

    def check(value: Any) -> list[float]:
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise refuse(f"expected a list of {length} {what}, got {value!r}")
        return [to_number(v, f"[{i}]") for i, v in enumerate(value)]

    json = {"type": "array", "items": NUMBER_JSON, "minItems": length, "maxItems": length}
    return Annotated[list[float], BeforeValidator(check), _Json(json)]


def numbers(what: str = "numbers") -> Any:
    """A list of numbers whose length the loader checks (it depends on the robot)."""

    def check(value: Any) -> list[float]:
        if not isinstance(value, (list, tuple)):
            raise refuse(f"expected a list of {what}, got {value!r}")
        return [to_number(v, f"[{i}]") for i, v in enumerate(value)]

    return Annotated[list[float], BeforeValidator(check), _Json({"type": "array", "items": NUMBER_JSON})]


def checked(check: Callable[[Any], Any], json: dict | Callable[[], dict], nullable: bool = False) -> Any:
    """A value ``check`` validates (raising :func:`refuse`), published as ``json``: for the few
    fields that take one of several shapes (a robot's name or a file or {file, tip}). Null
    reaches ``check`` only where ``nullable`` (it documents null); elsewhere it is refused."""
    return Annotated[object | None if nullable else object, BeforeValidator(check), _Json(json)]


def choice(values: tuple[str, ...], what: str, known: str | None = None) -> Any:
    """One of ``values`` (a ``what``, e.g. "measurement kind"), refused as "unknown WHAT 'x'
    (known: ...)"; ``known`` is how the list is written (default comma-separated)."""

    def check(value: Any) -> str:
        if value not in values:
            raise refuse(f"unknown {what} {value!r} (known: {known or ', '.join(values)})")
        return value

    return Annotated[str, BeforeValidator(check), _Json({"type": "string", "enum": list(values)})]


def _label(value: Any) -> Any:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise refuse(f"expected a name, got {value!r}")
    return value


# A name given in YAML (a point, a target, a corner): text, or a number YAML read as one (7).
Label = checked(_label, {"type": ["string", "integer"]})


def constant(value: str) -> Any:
    """A ``format`` field: exactly ``value`` (the format this fgcal reads)."""

    def check(given: Any) -> str:
        if given != value:
            raise refuse(f"unsupported format {given!r} (this fgcal reads {value})")
        return given

    return checked(check, {"const": value})


LENGTH_UNITS = ("m", "cm", "mm", "um")
ANGLE_UNITS = ("rad", "mrad", "deg")


def _units(value: Any) -> Any:
    if not isinstance(value, Mapping):
        raise refuse(f"expected a mapping like {{length: mm, angle: deg}}, got {value!r}")
    for key, given in value.items():
        if key not in ("length", "angle", "mass"):
            raise refuse("unknown unit kind (expected length, angle, mass)", str(key))
        if given is None:
            raise refuse("is null: give a unit, or leave the field out for its default", str(key))
    known = {"length": LENGTH_UNITS, "angle": ANGLE_UNITS, "mass": ("kg",)}
    for key, given in value.items():
        if given not in known[key]:
            raise refuse(f"unknown {key} unit {given!r} (known: {', '.join(known[key])})", key)
    return value


Units = checked(
    _units,
    {
        "type": "object",
        "description": "The units of the file's lengths and angles; masses are in kg. Left out: m and rad, "
        "except in a calibration config, whose units are then the dataset's.",
        "properties": {
            "length": {"enum": list(LENGTH_UNITS)},
            "angle": {"enum": list(ANGLE_UNITS)},
            "mass": {"enum": ["kg"], "default": "kg"},
        },
        "additionalProperties": False,
    },
)


class Pose(Schema):
    """A rigid pose: translation xyz (the file's length unit) and roll-pitch-yaw rpy (the file's
    angle unit; fixed axes x, then y, then z)."""

    xyz: vector(3) = [0.0, 0.0, 0.0]
    rpy: vector(3) = [0.0, 0.0, 0.0]


def one_or_more(model: type[Schema]) -> Any:
    """A section given once (a mapping) or several times (a list of them)."""
    return Annotated[
        Annotated[model, Tag("(one)")] | Annotated[list[model], Tag("(list)")],
        Discriminator(lambda v: "(list)" if isinstance(v, list) else "(one)"),
    ]


def _path(loc: tuple, at: str = "") -> str:
    out = ""
    for k, part in enumerate(loc):
        key = loc[k + 1 : k + 2] == ("[key]",)  # a mapping's key (not text) is at fault, not its value
        if isinstance(part, int) and not key:
            out += f"[{part}]"
        elif part == "[key]" or str(part).startswith(("function-", "(")):  # pydantic's or a union branch's tag
            continue
        else:
            out += f".{part}" if out else str(part)
    if at:
        out += at if at.startswith("[") or not out else f".{at}"
    return out


def _message(error: dict) -> str:
    kind, given, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    if kind == "fgcal":
        return ctx["message"]
    if kind == "missing":
        return "required field is missing"
    if kind == "string_type":
        return f"expected a string, got {given!r}"
    if kind in ("int_type", "int_from_float", "int_parsing"):
        return f"expected an integer, got {given!r}"
    if kind == "bool_type":
        return f"expected true or false, got {given!r}"
    if kind in ("list_type", "tuple_type"):
        return f"expected a list, got {type(given).__name__}"
    if kind in ("dict_type", "model_type"):
        return f"expected a mapping, got {type(given).__name__}"
    if kind == "literal_error":  # Fields.string's wording: 'x' is not one of a, b, c
        return f"{given!r} is not one of {ctx.get('expected', '').replace(chr(39), '').replace(' or ', ', ')}"
    bounds = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}
    if kind in bounds:
        limit = next(iter(ctx.values()))
        return f"must be {bounds[kind]} {limit}, got {given!r}"
    if kind == "too_short":
        return f"at least {ctx.get('min_length')} entries, got {given!r}"
    return error["msg"]


def validate(raw: Any, model: type[Schema], source: str | Path, prefix: str = "") -> Schema:
    """``raw`` (a YAML document) through ``model``; a refusal is the :class:`InputError` of its
    first error, naming ``source`` and the dotted field (one line: the CLI exits 2)."""
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        error = exc.errors(include_url=False)[0]
        ctx = error.get("ctx") or {}
        field = _path(error["loc"], ctx.get("at", "") if error["type"] == "fgcal" else "")
        if prefix:
            field = f"{prefix}.{field}" if field else prefix
        raise InputError(source, field or None, _message(error)) from None


def json_schema(model: type[Schema], title: str, description: str) -> dict:
    """The JSON Schema of ``model`` (draft 2020-12), for an editor's YAML language server."""
    schema = _without_null_defaults(model.model_json_schema())
    return {"$schema": JSON_SCHEMA_DIALECT, "title": title, "description": description,
            **{k: v for k, v in schema.items() if k not in ("title", "description")}}  # fmt: skip


def _without_null_defaults(node: Any) -> Any:
    """A field whose default is None only because it is optional and not nullable has no default
    to show (JSON's null would read as an allowed value)."""
    if isinstance(node, dict):
        out = {k: _without_null_defaults(v) for k, v in node.items()}
        nullable = any(isinstance(o, dict) and o.get("type") == "null" for o in node.get("anyOf", []))
        if "default" in out and out["default"] is None and not nullable:
            del out["default"]
        return out
    if isinstance(node, list):
        return [_without_null_defaults(v) for v in node]
    return node
