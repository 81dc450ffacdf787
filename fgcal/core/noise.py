"""The declared noise of measurements: one vocabulary for a dataset's header (what the
instrument states) and a calibration config (what the user states; it wins), in the file's
units, SI inside."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pydantic import Field, create_model

from .errors import InputError
from .fields import to_float
from .schema import Number, Schema
from .units import Units

# Field (SI) -> (file key, kind of unit, fgcal's default when nobody states it).
NOISE = {
    "camera_point_m": ("camera_point_sigma", "length", 1e-4),  # a point measured in the camera frame
    "tracker_m": ("tracker_sigma", "length", 1e-5),  # a tracker point, per coordinate
    "pixel_px": ("pixel_sigma_px", "pixel", 0.1),  # a detected image point, per coordinate
    "touch_m": ("touch_sigma", "length", 2e-5),  # where a touch puts the tool point, about its socket
    "spacing_m": ("spacing_sigma", "length", 1e-5),  # a known distance between touch points
    "pose_m": ("pose_sigma", "length", 2e-5),  # a measured pose's position, per coordinate
    "pose_rad": ("pose_angle_sigma", "angle", 1e-4),  # a measured pose's orientation, about each axis
    "distance_m": ("distance_sigma", "length", 5e-6),  # a ballbar's (1D gauge's) reading
    "contact_m": ("contact_sigma", "length", 1e-5),  # how far from touching a contact closes (ball on ball, on a plane)
}
KEYS = tuple(key for key, _, _ in NOISE.values())
# A sigma outside these (SI) is a typo: the best interferometer reads to 1 nm, and below about
# 1e-12 the whitened residuals overflow; above, the measurements would say nothing.
SMALLEST = {"length": 1e-10, "angle": 1e-10, "pixel": 1e-4}
LARGEST = {"length": 1.0, "angle": 1.0, "pixel": 1e3}
UNIT = {"length": "m", "angle": "rad", "pixel": "px"}


def stated_noise(section: Mapping | None, units: Units, source: str | Path, prefix: str = "noise") -> dict[str, float]:
    """The sigmas a ``noise`` section states (SI, by field; the file's schema has checked each is
    a positive number); the rest (absent) unstated."""
    scales = {"length": units.to_m, "angle": units.to_rad, "pixel": 1.0}
    stated = {}
    for field, (name, kind, _) in NOISE.items():
        if (section or {}).get(name) is None:
            continue
        sigma = to_float(section[name], source, f"{prefix}.{name}") * scales[kind]
        if not SMALLEST[kind] <= sigma <= LARGEST[kind]:
            raise InputError(
                source, f"{prefix}.{name}", f"{sigma:.3g} {UNIT[kind]} is no instrument's noise (from "
                f"{SMALLEST[kind]:g} to {LARGEST[kind]:g} {UNIT[kind]})",
            )  # fmt: skip
        stated[field] = sigma
    return stated


def noise_document(stated: dict[str, float], units: Units | None = None) -> dict[str, float]:
    """Stated sigmas (SI, by field) as a ``noise`` section in ``units`` (default SI: m, rad, px)."""
    units = units or Units()
    scales = {"length": units.to_m, "angle": units.to_rad, "pixel": 1.0}
    return {NOISE[field][0]: float(value) / scales[NOISE[field][1]] for field, value in stated.items()}


def defaults() -> dict[str, float]:
    return {field: default for field, (_, _, default) in NOISE.items()}



_WORDS = {"length": "the file's length unit", "angle": "the file's angle unit", "pixel": "px"}
# The schema of a ``noise`` section (fgcal.core.schema): each sigma positive, in the file's units.
NoiseSection = create_model(
    "Noise",
    __base__=Schema,
    __doc__="Declared standard deviations of the measurements, per coordinate, in the file's units.",
    **{
        key: (Number, Field(None, gt=0, description=f"sigma, {_WORDS[kind]} (default {default:g} SI)"))
        for key, kind, default in NOISE.values()
    },
)
