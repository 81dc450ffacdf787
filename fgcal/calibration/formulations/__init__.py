"""The registry of formulations: the one place that maps a config's ``formulation`` name to
the module implementing it (fgcal.calibration.problem.Formulation). Adding a formulation is
one module, its line here and its tests (docs/architecture.md)."""

from __future__ import annotations

from ..problem import Formulation
from .distances import DistanceReadings
from .pairs import Pairs
from .poses import MeasuredPoses
from .projection import Projection
from .static_camera import StaticCamera
from .touch import Touch
from .tracker import Tracker

REGISTRY: dict[str, type[Formulation]] = {
    cls.name: cls for cls in (Pairs, Tracker, Projection, Touch, MeasuredPoses, DistanceReadings, StaticCamera)
}
NAMES = tuple(REGISTRY)


def formulation(name: str) -> Formulation:
    """The formulation registered under ``name`` (KeyError otherwise: configs check names)."""
    return REGISTRY[name]()
