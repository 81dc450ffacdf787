"""Unit handling. Everything inside fgcal is SI (m, rad, kg, N m); files may declare
other units in a ``units`` mapping, converted once at load."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from .errors import InputError

LENGTH_TO_M = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}
ANGLE_TO_RAD = {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180.0}


@dataclass(frozen=True)
class Units:
    """Scale factors from a file's declared units to SI."""

    length: str = "m"
    angle: str = "rad"

    @property
    def to_m(self) -> float:
        return LENGTH_TO_M[self.length]

    @property
    def to_rad(self) -> float:
        return ANGLE_TO_RAD[self.angle]


def parse_units(raw: object, source: str | Path, field: str = "units", default: Units = Units()) -> Units:
    """Read a ``{length: mm, angle: deg}`` mapping; unknown keys or units are errors."""
    if raw is None:
        return default
    if not isinstance(raw, Mapping):
        raise InputError(source, field, f"expected a mapping like {{length: mm, angle: deg}}, got {raw!r}")
    unknown = set(raw) - {"length", "angle", "mass"}
    if unknown:
        raise InputError(source, f"{field}.{sorted(unknown)[0]}", "unknown unit kind (expected length, angle, mass)")
    for kind in ("length", "angle", "mass"):
        if kind in raw and raw[kind] is None:
            raise InputError(source, f"{field}.{kind}", "is null: give a unit, or leave the field out for its default")
    length = str(raw.get("length", default.length))
    angle = str(raw.get("angle", default.angle))
    if length not in LENGTH_TO_M:
        raise InputError(source, f"{field}.length", f"unknown length unit {length!r} (known: {', '.join(LENGTH_TO_M)})")
    if angle not in ANGLE_TO_RAD:
        raise InputError(source, f"{field}.angle", f"unknown angle unit {angle!r} (known: {', '.join(ANGLE_TO_RAD)})")
    if str(raw.get("mass", "kg")) != "kg":
        raise InputError(source, f"{field}.mass", f"unknown mass unit {raw.get('mass')!r} (only kg)")
    return Units(length=length, angle=angle)
