"""The one checked base of every fgcal factor, and the shared evaluation of measurement factors.

GTSAM's Python ``CustomFactor`` crashes the interpreter when a Jacobian is left unset or has
the wrong shape. Every factor here derives from :class:`CheckedFactor`, whose callback checks
the residual and each Jacobian (shape, finiteness) before handing them to GTSAM, and raises
:class:`FactorError` otherwise. GTSAM propagates that exception to the caller.

Measurement factors depend directly on the parameter vector P and on auxiliary unknowns
(fixture pose, tracker pose, tool points, intrinsics); the kinematics of every configuration
comes from one shared, vectorised evaluation. A :class:`MeasurementSet` holds the
measurements of one kind (all point-pair groups, all images, all tracker configurations),
computes every residual and Jacobian in one vectorised call, caches it on the variables'
values, and is one :class:`MeasurementFactor` in the graph: one Python callback per
evaluation of the whole set, however many measurements it holds (a factor per measurement
would cost a callback each, most of a solve's time in GTSAM's optimiser).
"""

from __future__ import annotations

import copy
import itertools
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..core.se3 import skew

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


class OutsideModelError(ValueError):
    """The variables are where the measurement model breaks down (a point behind the camera):
    a trial step went too far, or the starting values are far off. ``configuration``: the index,
    among the measurement set's configurations, of the one where it broke down (if known)."""

    def __init__(self, message: str, configuration: int | None = None) -> None:
        super().__init__(message)
        self.configuration = configuration


# What a measurement row costs (whitened) where the model breaks down during a trial step: so
# large that the optimiser rejects the step and shortens the next one, yet finite.
BREAKDOWN_RESIDUAL = 1e100


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
        residual, blocks = self.evaluate(inputs, jacobians)
        return check_outputs(self, residual, blocks, self.dim, jacobians)

    def _callback(self, _this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        residual, blocks = self.checked(self.read(values), H is not None)
        if H is not None:
            for i, block in enumerate(blocks):
                H[i] = block
        return residual


def check_outputs(owner, residual, blocks: list, dim: int, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
    """The residual as a (dim,) array and, with ``jacobians``, one (dim, tangent dim) block
    per variable of ``owner`` (a factor or a measurement set), all finite; FactorError
    otherwise, before anything reaches GTSAM."""
    name = type(owner).__name__
    residual = np.asarray(residual, dtype=float).reshape(-1)
    if residual.shape != (dim,):
        raise FactorError(f"{name}: residual has shape {residual.shape}, expected ({dim},)")
    if not np.isfinite(residual).all():
        raise FactorError(f"{name} on keys {[v[0] for v in owner.variables]}: non-finite residual {residual}")
    if not jacobians:
        return residual, []
    if len(blocks) != len(owner.variables):
        raise FactorError(f"{name}: {len(blocks)} Jacobians for {len(owner.variables)} variables")
    checked = []
    for block, (key, kind, width) in zip(blocks, owner.variables, strict=True):
        block = np.asarray(block, dtype=float)
        if block.shape != (dim, width):
            raise FactorError(
                f"{name}: Jacobian for key {key} ({kind}) has shape {block.shape}, expected ({dim}, {width})"
            )
        if not np.isfinite(block).all():
            raise FactorError(f"{name} on keys {[v[0] for v in owner.variables]}: non-finite Jacobian")
        checked.append(block)
    return residual, checked


def point_jacobian(rotation: np.ndarray, point_local: np.ndarray) -> np.ndarray:
    """d (T p) / d xi for the body perturbation ``T Exp(xi)``, xi = [omega, v]: ``[-R [p]x, R]``.

    Stacked: ``rotation`` (..., 3, 3) and ``point_local`` (..., 3) give (..., 3, 6).
    """
    rotation = np.asarray(rotation, dtype=float)
    left = -rotation @ skew(point_local)
    return np.concatenate([left, np.broadcast_to(rotation, left.shape)], axis=-1)


def gaussian(sigmas: np.ndarray) -> gtsam.noiseModel.Base:
    """Diagonal Gaussian noise with these standard deviations."""
    return gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=float))


# -- robust losses inside a factor ---------------------------------------------------------


@dataclass(frozen=True)
class RobustLoss:
    """A Huber or Cauchy loss rho(s) on the whitened norm s of each robust unit (one
    observation: a pixel, a tracker point; or a whole point-pair group), threshold ``k`` in
    sigmas.

    It is applied inside the factor, per unit, as a reweighted least-squares residual
    ``r' = phi(s) r / s`` with ``phi = sqrt(2 rho(s))``, so that ``|r'|^2 / 2 = rho(s)``, and
    its exact Jacobian ``J' = (phi/s)(I - u u^T) J + phi' u u^T J`` (u = r/s). Gauss-Newton on
    r' then has the gradient of sum rho, so it converges to the M-estimate, and GTSAM's
    error is the robust cost. (GTSAM's own robust noise models act on a whole factor, and a
    factor here carries many observations.)
    """

    kind: str
    k: float

    def __post_init__(self) -> None:
        if self.kind not in ("huber", "cauchy"):
            raise ValueError(f"unknown robust loss {self.kind!r} (huber, cauchy)")
        if not self.k > 0:
            raise ValueError(f"robust threshold must be positive, got {self.k}")

    def phi(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """sqrt(2 rho(s)) and its derivative, for norms s >= 0."""
        k = self.k
        if self.kind == "huber":
            inside = s <= k
            rho = np.where(inside, 0.5 * s * s, k * s - 0.5 * k * k)
            d_rho = np.where(inside, s, k)
        else:
            rho = 0.5 * k * k * np.log1p((s / k) ** 2)
            d_rho = s / (1.0 + (s / k) ** 2)
        phi = np.sqrt(2.0 * rho)
        d_phi = np.where(phi > 0, d_rho / np.where(phi > 0, phi, 1.0), 1.0)
        return phi, d_phi

    def apply(
        self, residual: np.ndarray, jacobian: np.ndarray | None, starts: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Transform whitened rows (R,) and their Jacobian (R, C); units are the contiguous
        row ranges beginning at ``starts``."""
        lengths = np.diff(np.append(starts, len(residual)))
        s = np.sqrt(np.add.reduceat(residual**2, starts))
        phi, d_phi = self.phi(s)
        tiny = s < 1e-12  # rho ~ s^2/2 there: r' = r
        ratio = np.where(tiny, 1.0, phi / np.where(tiny, 1.0, s))
        out = residual * np.repeat(ratio, lengths)
        if jacobian is None:
            return out, None
        u = residual / np.repeat(np.where(tiny, 1.0, s), lengths)
        u_J = np.add.reduceat(u[:, None] * jacobian, starts, axis=0)  # (U, C): u^T J per unit
        extra = np.where(tiny, 0.0, d_phi - ratio)
        return out, jacobian * np.repeat(ratio, lengths)[:, None] + (u * np.repeat(extra, lengths))[:, None] * (
            np.repeat(u_J, lengths, axis=0)
        )


# -- measurement sets: many factors of one kind, evaluated at once ---------------------------


@dataclass
class Evaluation:
    """Rows of every measurement of a set: residual (R,) and one Jacobian (R, dim) per
    variable of the set."""

    residual: np.ndarray
    blocks: list[np.ndarray]


class MeasurementSet:
    """Measurements of one kind evaluated in one vectorised call (see the module docstring).

    Subclasses set ``self.variables`` ([(key, kind, dim)]), ``self.sigma`` (R,) per row and
    ``self.unit_starts`` (first row of each robust unit, i.e. each observation), then call
    ``super().__init__``, and implement :meth:`compute`.
    """

    # Evaluations kept. Levenberg-Marquardt asks at its linearisation point and one trial at a
    # time: with 2 the bundled cells, the FARO set and the seed cell at 3000 configurations
    # evaluate as often as with 4.
    CACHED = 2
    # Whether the kept evaluations hold their Jacobians. Levenberg-Marquardt linearises once
    # where it linearises, and a large set's Jacobians (tens of MB at thousands of
    # configurations) would stay alive beside GTSAM's copy while it solves the step. iSAM2
    # linearises an image's factor again at the same point on later updates: the online
    # calibrator keeps them.
    keep_jacobians = False
    row_unit = "m"  # of every row's residual, unless row_units says otherwise

    variables: list[tuple[int, str, int]]
    sigma: np.ndarray
    unit_starts: np.ndarray

    def __init__(self, robust: RobustLoss | None = None) -> None:
        self.variables = [(key, kind, dim if dim is not None else _DIMS[kind]) for key, kind, dim in self.variables]
        self.robust = robust
        self.n_rows = len(self.sigma)
        if not self.n_rows:
            raise ValueError(f"{type(self).__name__}: no measurement")
        self._cache: OrderedDict[bytes, dict] = OrderedDict()

    def forget(self) -> None:
        """Forget the cached evaluations (a graph not in use: its next use evaluates again)."""
        self._cache.clear()

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        """Residuals (and Jacobians) of every row at the variables' values ``inputs``."""
        raise NotImplementedError

    def factor(self) -> MeasurementFactor:
        """The set as one GTSAM factor."""
        if not self.variables:
            raise ValueError(f"{type(self).__name__}: no variable to estimate (it can still be evaluated)")
        return MeasurementFactor(self)

    def read(self, values: gtsam.Values) -> list:
        return [_GETTERS[kind](values, key) for key, kind, _ in self.variables]

    def whitened(self, inputs: list, jacobians: bool, robust: bool = True) -> Evaluation:
        """Rows divided by their sigma, then (if ``robust`` and the set has a loss) passed
        through the robust loss; cached on the inputs' values (the Jacobians only with
        ``keep_jacobians``)."""
        key = b"".join(_bytes(value) for value in inputs)
        entry = self._cache.get(key)
        if entry is None:
            if len(self._cache) >= self.CACHED:
                self._cache.popitem(last=False)
            entry = self._cache[key] = {}
        kind = "robust" if robust and self.robust is not None else "plain"
        cached = entry.get(kind)
        if cached is not None and (cached.blocks or not jacobians or not self.variables):
            return cached
        raw = None if jacobians else entry.get("raw")
        blocks = []
        if raw is None:
            computed = self.compute(inputs, jacobians)
            # Checked once for all the set's factors, which then only slice it.
            raw, blocks = check_outputs(self, computed.residual, computed.blocks, self.n_rows, jacobians)
            entry["raw"] = raw
        scale = 1.0 / self.sigma
        residual = raw * scale
        stacked = None
        if jacobians:
            # Whitened into one array, the variables' blocks views of it: no temporary copy.
            edges = np.cumsum([0, *[dim for _, _, dim in self.variables]])
            stacked = np.empty((self.n_rows, edges[-1]))
            for block, a, b in zip(blocks, edges[:-1], edges[1:], strict=True):
                np.multiply(block, scale[:, None], out=stacked[:, a:b])
            del blocks, computed
        if kind == "robust":
            residual, stacked = self.robust.apply(residual, stacked, self.unit_starts)
        blocks = []
        if jacobians:
            blocks = [stacked[:, a:b] for a, b in itertools.pairwise(edges)]
        evaluation = Evaluation(residual, blocks)
        entry[kind] = evaluation if self.keep_jacobians else Evaluation(residual, [])
        return evaluation

    def unit_norms(self, values: gtsam.Values) -> np.ndarray:
        """Whitened norm of each robust unit (observation), without the robust loss."""
        residual = self.whitened(self.read(values), False, robust=False).residual
        return np.sqrt(np.add.reduceat(residual**2, self.unit_starts))

    def unit_rms(self, values: gtsam.Values) -> np.ndarray:
        """Whitened RMS per row of each robust unit (its norm over the square root of its rows)."""
        return self.unit_norms(values) / np.sqrt(self.unit_dims)

    @property
    def unit_dims(self) -> np.ndarray:
        """Rows of each robust unit."""
        return np.diff(np.append(self.unit_starts, self.n_rows))

    def row_units(self) -> dict[str, np.ndarray]:
        """Unit (m, rad, px) -> mask of the rows in that unit."""
        return {self.row_unit: np.ones(self.n_rows, dtype=bool)}

    def raw_residual(self, values: gtsam.Values) -> np.ndarray:
        return self.whitened(self.read(values), False, robust=False).residual * self.sigma


class MeasurementFactor(CheckedFactor):
    """A :class:`MeasurementSet` as one factor: the set's whitened (and robust) residual
    ``r(P, aux) / sigma``; the set's docstring states r.

    Where the model breaks down (:class:`OutsideModelError`, or a non-finite residual) while the
    optimiser only costs a trial step, every row costs BREAKDOWN_RESIDUAL: the step is
    rejected and a shorter one tried. At a linearisation point it is an error."""

    def __init__(self, measurements: MeasurementSet) -> None:
        self.measurements = measurements
        rows = measurements.n_rows
        super().__init__(measurements.variables, gtsam.noiseModel.Unit.Create(rows), np.ones(rows))

    def evaluate(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        try:
            evaluation = self.measurements.whitened(inputs, jacobians)
        except (OutsideModelError, FactorError):
            if jacobians:
                raise
            return np.full(self.dim, BREAKDOWN_RESIDUAL), []
        return evaluation.residual, evaluation.blocks

    def checked(self, inputs: list, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray]]:
        # The set checked its evaluation (shapes, finiteness; the robust loss keeps both).
        return self.evaluate(inputs, jacobians)


def _bytes(value) -> bytes:
    if isinstance(value, np.ndarray):
        return value.tobytes()
    return np.asarray(value.matrix()).tobytes()


def row_starts(counts: Sequence[int]) -> np.ndarray:
    """First row of each of consecutive blocks of ``counts`` rows."""
    return np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
