"""Priors on the robot's parameters: a Gaussian around the nominal value per parameter, stated in a
config's ``bounds:`` per class of parameter (length, angle, compliance, motion, mass), per kind
(``alpha``, ``kz``, ...) or per parameter (``d6``), the most specific winning.

They stand in for bounds (SPEC section 4) and regularise a short or one-sided data set as a
ridge term does. fgcal's own soft bounds (10 mm on the arm's lengths, 0.5 deg on the motion
history's terms) only keep the solve from absurd values; the priors a config states also count
as information in the identifiability analysis.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import to_float
from ..core.units import Units
from ..model.parameters import (
    COMPLIANCE_KINDS,
    COUPLED_COMPLIANCE,
    JOINT_KINDS,
    LENGTH_KINDS,
    MASS_KIND,
    MOTION_KINDS,
    ORIGIN_CORRECTION_KINDS,
    is_joint_length,
    split_name,
    unit_of,
)

CLASSES = ("length", "angle", "compliance", "motion", "mass")
KINDS = (*JOINT_KINDS, COUPLED_COMPLIANCE, *ORIGIN_CORRECTION_KINDS, *MOTION_KINDS)
# fgcal's soft bounds when a config states none (SI): they keep lengths from absorbing angular
# errors and the motion terms from running off, and are not counted as information.
DEFAULTS = {"length": 0.01, "motion": float(np.radians(0.5))}


def class_of(name: str) -> str:
    kind, _ = split_name(name)
    if kind == MASS_KIND:
        return "mass"
    if kind in COMPLIANCE_KINDS:
        return "compliance"
    if kind in MOTION_KINDS:
        return "motion"
    return "length" if kind in LENGTH_KINDS else "angle"


@dataclass(frozen=True)
class Priors:
    """Prior sigmas as stated (in the config's units, converted per parameter by its SI unit),
    by class, kind and parameter name."""

    units: Units = field(default_factory=Units)
    by_class: Mapping[str, float] = field(default_factory=dict)
    by_kind: Mapping[str, float] = field(default_factory=dict)
    by_name: Mapping[str, float] = field(default_factory=dict)
    source: str = "<defaults>"

    def _si(self, name: str, value: float) -> float:
        unit = unit_of(name)
        scale = {"m": self.units.to_m, "rad": self.units.to_rad, "rad/(N m)": self.units.to_rad, "1": 1.0}[unit]
        return value * scale

    def stated(self, name: str) -> float | None:
        """The prior sigma a config states for ``name`` (SI), or None."""
        kind, owner = split_name(name)
        if name in self.by_name:
            return self._si(name, self.by_name[name])
        if isinstance(owner, int) and kind in self.by_kind:
            return self._si(name, self.by_kind[kind])
        joint_or_mass = isinstance(owner, int) or kind == MASS_KIND
        if joint_or_mass and class_of(name) in self.by_class:  # base and tool only by name
            return self._si(name, self.by_class[class_of(name)])
        return None

    def sigma(self, name: str) -> float | None:
        """The prior sigma in effect for ``name`` (SI): the stated one, else fgcal's soft bound
        (the arm's lengths, the motion terms), else None (free)."""
        stated = self.stated(name)
        if stated is not None:
            return stated
        if is_joint_length(name):
            return DEFAULTS["length"]
        if class_of(name) == "motion":
            return DEFAULTS["motion"]
        return None

    def check_names(self, parameter_names: list[str], robot_name: str) -> None:
        """Every parameter a config names is one of the robot's."""
        for name in self.by_name:
            if name not in parameter_names:
                examples = ", ".join(parameter_names[:4])
                raise InputError(self.source, f"bounds.{name}", f"not a parameter of {robot_name} (e.g. {examples})")


def parse_priors(bounds: Mapping | None, units: Units, source: str | Path) -> Priors:
    """``bounds: {length: 0.01, alpha: 0.05, d6: 0.5, kz2: 2e-7}``: a class, a kind or a
    parameter name, each a positive sigma in the config's units (lengths, angles; compliances in
    angle units per N m; mass scales unitless). ``bounds`` is the config's section as its schema
    validated it (each sigma a positive number)."""
    by_class, by_kind, by_name = {}, {}, {}
    for key, sigma in (bounds or {}).items():
        key = str(key)
        value = to_float(sigma, source, f"bounds.{key}")
        if key in CLASSES:
            by_class[key] = value
        elif key in KINDS:
            by_kind[key] = value
        else:
            try:
                split_name(key)
            except ValueError:
                raise InputError(
                    source, f"bounds.{key}",
                    f"not a class ({', '.join(CLASSES)}), a kind ({', '.join(KINDS)}) or a parameter name",
                ) from None  # fmt: skip
            by_name[key] = value
    return Priors(units, by_class, by_kind, by_name, str(source))
