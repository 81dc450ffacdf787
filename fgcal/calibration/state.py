"""The estimate of one calibration: the parameter vector and the auxiliary unknowns of its
formulation (an instrument's pose, points on the tool, fixed points in the cell, ...)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

# Tangent dimension of each kind of auxiliary unknown (points and vectors: their length).
_DIMS = {"pose3": 6, "rot3": 3}


@dataclass(frozen=True)
class Auxiliary:
    """One auxiliary unknown: its kind and value (SI).

    - ``pose3``: a 4x4 pose (T_a_b as the name says: ``tracker`` is T_T_W);
    - ``rot3``: a 3x3 rotation;
    - ``points``: (k, 3) points, one per label (a GTSAM vector of 3k);
    - ``vector``: (k,) values, one per label (intrinsics).

    ``labels`` name the points or entries; ``prior_sigmas`` (vector only) put a Gaussian prior
    around ``prior_mean`` on it (intrinsics from an earlier calibration).
    """

    kind: str
    value: np.ndarray
    labels: tuple[str, ...] = ()
    prior_mean: np.ndarray | None = None
    prior_sigmas: np.ndarray | None = None

    @property
    def dim(self) -> int:
        return _DIMS.get(self.kind, int(np.size(self.value)))

    def to_gtsam(self):
        if self.kind == "pose3":
            return gtsam.Pose3(self.value)
        if self.kind == "rot3":
            return gtsam.Rot3(self.value)
        return np.asarray(self.value, dtype=float).reshape(-1)

    def from_values(self, values: gtsam.Values, key: int) -> Auxiliary:
        """This unknown with the value ``values`` holds at ``key``."""
        if self.kind == "pose3":
            value = values.atPose3(key).matrix()
        elif self.kind == "rot3":
            value = values.atRot3(key).matrix()
        else:
            value = values.atVector(key).reshape(np.shape(self.value))
        return replace(self, value=value)

    @property
    def gtsam_kind(self) -> str:
        """The factors' name of this unknown's kind (fgcal.factors.base)."""
        return self.kind if self.kind in _DIMS else "vector"


@dataclass(frozen=True)
class State:
    """Full parameter vector (SI, the robot's parameter_names order) and the auxiliary
    unknowns by name (their order is the order of the graph's variables)."""

    params: np.ndarray
    aux: Mapping[str, Auxiliary] = field(default_factory=dict)

    def value(self, name: str) -> np.ndarray:
        return self.aux[name].value

    def get(self, name: str) -> np.ndarray | None:
        return self.aux[name].value if name in self.aux else None

    @property
    def n_auxiliary(self) -> int:
        """Number of auxiliary unknowns (tangent dimensions)."""
        return sum(a.dim for a in self.aux.values())

    def with_params(self, params: np.ndarray) -> State:
        return replace(self, params=np.asarray(params, dtype=float))

    def with_aux(self, **values: np.ndarray) -> State:
        """The state with these auxiliary unknowns set to new values (kinds and labels kept)."""
        aux = dict(self.aux)
        for name, value in values.items():
            aux[name] = replace(aux[name], value=np.asarray(value, dtype=float))
        return replace(self, aux=aux)
