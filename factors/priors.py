"""Priors standing in for bounds (SPEC section 4: lengths bounded, angles not)."""

from __future__ import annotations

import numpy as np

from .base import CheckedFactor, gaussian


class ParameterBoundFactor(CheckedFactor):
    """``r_i = P[i] - nominal_i`` for the bounded entries i of the parameter vector, with
    sigma = the bound's tolerance (m): a soft bound that keeps lengths from absorbing
    angular errors."""

    def __init__(
        self, params_key: int, n_params: int, indices: np.ndarray, nominal: np.ndarray, tolerances: np.ndarray
    ) -> None:
        self.indices = np.asarray(indices, dtype=int)
        self.nominal = np.asarray(nominal, dtype=float)
        self.selection = np.zeros((len(self.indices), n_params))
        self.selection[np.arange(len(self.indices)), self.indices] = 1.0
        super().__init__([(params_key, "vector", n_params)], gaussian(tolerances), tolerances)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        params = np.asarray(inputs[0], dtype=float)
        residual = params[self.indices] - self.nominal
        return residual, ([self.selection] if jacobians else [])


class RandomWalkFactor(CheckedFactor):
    """``r = p_c - p_{c-1}``: the parameters of two consecutive work cycles differ by a random
    walk step with the given sigmas (SI units of each parameter)."""

    def __init__(self, previous_key: int, key: int, sigmas: np.ndarray) -> None:
        dim = len(sigmas)
        self._identity = np.eye(dim)
        super().__init__([(previous_key, "vector", dim), (key, "vector", dim)], gaussian(sigmas), sigmas)

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        previous, current = (np.asarray(v, dtype=float) for v in inputs)
        return current - previous, ([-self._identity, self._identity] if jacobians else [])
