"""Custom GTSAM factors of fgcal (installed as ``fgcal.factors``). Every factor derives
from :class:`CheckedFactor`; its docstring states the residual."""

from .base import CheckedFactor, FactorError, gaussian, point_jacobian
from .kinematic import KinematicFactor
from .point_pair import PointPairFactor
from .priors import ParameterBoundFactor, RandomWalkFactor
from .projection import ProjectionFactor, project
from .tracker import DistanceFactor, PoseFactor, TrackerPointFactor

__all__ = [
    "CheckedFactor",
    "DistanceFactor",
    "FactorError",
    "KinematicFactor",
    "ParameterBoundFactor",
    "PointPairFactor",
    "PoseFactor",
    "ProjectionFactor",
    "RandomWalkFactor",
    "TrackerPointFactor",
    "gaussian",
    "point_jacobian",
    "project",
]
