"""The one checked base of every fgcal factor.

GTSAM's Python ``CustomFactor`` crashes the interpreter when a Jacobian is left unset or has
the wrong shape. Every factor here derives from :class:`CheckedFactor`, whose callback checks
the residual and each Jacobian (shape, finiteness) before handing them to GTSAM, and raises
:class:`FactorError` otherwise. GTSAM propagates that exception to the caller.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import gtsam
import numpy as np

# Variable kinds: how to read them from gtsam.Values and their tangent dimension.
_GETTERS = {
    "pose3": lambda values, key: values.atPose3(key),
    "point3": lambda values, key: values.atPoint3(key),
    "rot3": lambda values, key: values.atRot3(key),
    "vector": lambda values, key: values.atVector(key),
}
_DIMS = {"pose3": 6, "point3": 3, "rot3": 3}


class FactorError(RuntimeError):
    """A factor produced a residual or Jacobian of the wrong shape, or a non-finite value."""


class CheckedFactor:
    """Base of fgcal's factors. Subclasses set their state, then call ``super().__init__`` with
    their variables ``[(key, kind, dim)]`` and a noise model, and implement :meth:`evaluate`.

    ``self.factor`` is the ``gtsam.CustomFactor`` to add to a graph; ``self.sigmas`` the
    standard deviations of the residual (before any robust loss), for whitening elsewhere.
    """

    def __init__(
        self, variables: Sequence[tuple[int, str, int | None]], noise: gtsam.noiseModel.Base, sigmas: np.ndarray
    ) -> None:
        self.variables = [(key, kind, dim if dim is not None else _DIMS[kind]) for key, kind, dim in variables]
        for key, kind, _ in self.variables:
            if kind not in _GETTERS:
                raise ValueError(f"unknown variable kind {kind!r} for key {key}")
        self.sigmas = np.asarray(sigmas, dtype=float)
        self.dim = len(self.sigmas)
        if noise.dim() != self.dim:
            raise ValueError(f"{type(self).__name__}: noise model has dimension {noise.dim()}, residual {self.dim}")
        self.keys = [key for key, _, _ in self.variables]
        # The callback runs on a shallow copy that does not hold ``factor``: a callback bound
        # to self would close a cycle through C++ (self -> factor -> callback -> self) that
        # Python's collector cannot see, and every factor would outlive its graph. Subclasses
        # therefore set their state before calling this constructor.
        evaluator = copy.copy(self)
        self.factor = gtsam.CustomFactor(noise, self.keys, evaluator._callback)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        """Residual and, if ``jacobians``, one Jacobian per variable (residual dim x tangent dim)."""
        raise NotImplementedError

    def read(self, values: gtsam.Values) -> list:
        return [_GETTERS[kind](values, key) for key, kind, _ in self.variables]

    def checked(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        """:meth:`evaluate` with every output checked; used by the GTSAM callback and by
        analyses that need the Jacobians without GTSAM."""
        name = type(self).__name__
        residual, blocks = self.evaluate(inputs, jacobians)
        residual = np.asarray(residual, dtype=float).reshape(-1)
        if residual.shape != (self.dim,):
            raise FactorError(f"{name}: residual has shape {residual.shape}, expected ({self.dim},)")
        if not np.isfinite(residual).all():
            raise FactorError(f"{name} on keys {self.keys}: non-finite residual {residual}")
        if not jacobians:
            return residual, []
        if len(blocks) != len(self.variables):
            raise FactorError(f"{name}: {len(blocks)} Jacobians for {len(self.variables)} variables")
        checked = []
        for block, (key, kind, dim) in zip(blocks, self.variables, strict=True):
            block = np.asarray(block, dtype=float)
            if block.shape != (self.dim, dim):
                raise FactorError(
                    f"{name}: Jacobian for key {key} ({kind}) has shape {block.shape}, expected ({self.dim}, {dim})"
                )
            if not np.isfinite(block).all():
                raise FactorError(f"{name} on keys {self.keys}: non-finite Jacobian")
            checked.append(block)
        return residual, checked

    def _callback(self, _this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        residual, blocks = self.checked(self.read(values), H is not None)
        if H is not None:
            for i, block in enumerate(blocks):
                H[i] = block
        return residual


def point_jacobian(rotation: np.ndarray, point_local: np.ndarray) -> np.ndarray:
    """d (T p) / d xi for the body perturbation ``T Exp(xi)``, xi = [omega, v]: ``[-R [p]x, R]``."""
    skew = np.array(
        [
            [0.0, -point_local[2], point_local[1]],
            [point_local[2], 0.0, -point_local[0]],
            [-point_local[1], point_local[0], 0.0],
        ]
    )
    return np.hstack([-rotation @ skew, rotation])


def gaussian(sigmas: np.ndarray, robust: tuple[str, float] | None = None) -> gtsam.noiseModel.Base:
    """Diagonal Gaussian noise, optionally wrapped in a Huber or Cauchy loss with threshold k
    (in units of sigma)."""
    base = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))
    if robust is None:
        return base
    kind, threshold = robust
    estimators = {"huber": gtsam.noiseModel.mEstimator.Huber, "cauchy": gtsam.noiseModel.mEstimator.Cauchy}
    if kind not in estimators:
        raise ValueError(f"unknown robust loss {kind!r} (huber, cauchy)")
    return gtsam.noiseModel.Robust.Create(estimators[kind].Create(threshold), base)
