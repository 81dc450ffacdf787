"""Custom GTSAM factors of fgcal (installed as ``fgcal.factors``). Every factor derives
from :class:`CheckedFactor`. Measurement factors come from a :class:`MeasurementSet` of their
kind, whose docstring states the residual; they depend directly on the parameter vector."""

from .base import (
    CheckedFactor,
    Evaluation,
    FactorError,
    MeasurementFactor,
    MeasurementSet,
    OutsideModelError,
    RobustLoss,
    gaussian,
    point_jacobian,
)
from .contact import PlaneContacts, SelfContacts, TipDistances
from .kinematics import Kinematics
from .point_pair import PointPairs, helmert
from .priors import ParameterBoundFactor, RandomWalkFactor
from .projection import BehindCameraError, LinkProjections, Projections, StaticProjections, project
from .touch import SocketSpacings, TouchPoints
from .tracker import Distances, Poses, TrackerPoints

__all__ = [
    "BehindCameraError",
    "CheckedFactor",
    "Distances",
    "Evaluation",
    "FactorError",
    "Kinematics",
    "LinkProjections",
    "MeasurementFactor",
    "MeasurementSet",
    "OutsideModelError",
    "ParameterBoundFactor",
    "PlaneContacts",
    "PointPairs",
    "Poses",
    "Projections",
    "RandomWalkFactor",
    "RobustLoss",
    "SelfContacts",
    "SocketSpacings",
    "StaticProjections",
    "TipDistances",
    "TouchPoints",
    "TrackerPoints",
    "gaussian",
    "helmert",
    "point_jacobian",
    "project",
]
