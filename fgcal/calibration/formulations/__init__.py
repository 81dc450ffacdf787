"""The registry of formulations: the one place that maps a config's ``formulation`` name to
the module implementing it (fgcal.calibration.problem.Formulation). Adding a formulation is
one module, its line here and its tests (docs/architecture.md)."""

from __future__ import annotations

from ..problem import Formulation
from .distances import DistanceReadings
from .pairs import Pairs
from .planes import Planes
from .poses import MeasuredPoses
from .projection import Projection
from .self_contact import SelfContact
from .self_observation import SelfObservation
from .static_camera import StaticCamera
from .tip_gauge import TipGauge
from .touch import Touch
from .tracker import Tracker

REGISTRY: dict[str, type[Formulation]] = {
    cls.name: cls
    for cls in (
        Pairs,
        Tracker,
        Projection,
        Touch,
        MeasuredPoses,
        DistanceReadings,
        StaticCamera,
        SelfContact,
        Planes,
        TipGauge,
        SelfObservation,
    )
}
NAMES = tuple(REGISTRY)


def formulation(name: str) -> Formulation:
    """The formulation registered under ``name`` (KeyError otherwise: configs check names)."""
    return REGISTRY[name]()


def from_measured(measured: list[str], camera_on_flange: bool) -> list[str]:
    """The formulations that read a dataset's measured tables, in the registry's order (the
    first is the default of a config that names none). A camera's pixels are read by the
    formulation of where the camera is: on the flange (a mounting given) or fixed in the cell."""
    out = []
    for name, cls in REGISTRY.items():
        if cls.kind not in measured:
            continue
        if cls.instrument in ("camera", "static_camera") and (cls.instrument == "camera") != camera_on_flange:
            continue
        out.append(name)
    return out
