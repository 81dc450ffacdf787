"""The factor graph of one stage: the parameter vector P (the released parameters), the
formulation's auxiliary unknowns, the soft bounds of the joint lengths, any priors of the
auxiliary unknowns, and the formulation's measurement sets, each one factor that depends
directly on P.

There are no per-configuration pose variables: a measurement set computes the poses of its
configurations from P through one vectorised kinematics evaluation shared by every set of the
graph (fgcal.calibration.batch), so a linearisation costs one kinematics pass and one Python
callback per set.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..factors import MeasurementSet, ParameterBoundFactor, RobustLoss, gaussian
from .batch import BatchKinematics
from .goodness import chi_median
from .problem import Keys, Problem, keys_of, values_of
from .state import State


@dataclass
class StageGraph:
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values  # the starting values
    kinematics: BatchKinematics
    keys: Keys
    released: list[str]
    state: State  # the state the stage starts from (kinds and labels of the unknowns)
    measurements: list[MeasurementSet]  # the first is the formulation's main set
    robust_scale: float | None = None  # scale of the robust loss's threshold, when there is one

    def forget(self) -> None:
        """Free the evaluations cached for this graph, tens of MB at thousands of
        configurations, while another graph is in use; a later use evaluates again."""
        self.kinematics.forget()
        for measurements in self.measurements:
            measurements.forget()

    @property
    def dims(self) -> dict[str, tuple[int, int]]:
        """Name (P for the parameters) -> (key, tangent dimension) of every variable."""
        out = {"P": (self.keys.params, len(self.released))} if self.keys.params is not None else {}
        for name, aux in self.state.aux.items():
            out[name] = (self.keys[name], aux.dim)
        return out


def build_graph(problem: Problem, released: Sequence[str], state: State) -> StageGraph:
    kinematics = problem.kinematics(state, released, problem.observations)
    keys = keys_of(state, bool(released))
    values = values_of(state, keys, kinematics.base[kinematics.index])
    graph = gtsam.NonlinearFactorGraph()
    nominal = problem.robot.nominal_parameters()
    # Priors around nominal: those the config states (bounds:) and fgcal's soft bounds (the
    # arm's lengths, the motion history's terms; calibration.priors).
    prior_sigmas = {i: problem.priors.sigma(name) for i, name in enumerate(released)}
    bounded = [i for i, sigma in prior_sigmas.items() if sigma is not None]
    sigmas = [prior_sigmas[i] for i in bounded]
    if bounded:
        graph.add(
            ParameterBoundFactor(
                keys.params,
                len(released),
                np.array(bounded),
                np.array([nominal[released[i]] for i in bounded]),
                np.array(sigmas),
            ).factor
        )
    for name, aux in state.aux.items():
        if aux.prior_sigmas is not None:
            graph.add(gtsam.PriorFactorVector(keys[name], aux.prior_mean, gaussian(aux.prior_sigmas)))

    def measurement_sets(robust: RobustLoss | None) -> list[MeasurementSet]:
        return problem.formulation.measurement_sets(problem, problem.observations, kinematics, keys, state, robust)

    measurements = measurement_sets(None)
    stage = StageGraph(graph, values, kinematics, keys, list(released), state, measurements)
    robust = problem.settings.robust.get(problem.formulation.kind)
    if robust is not None:
        # The loss's threshold is in units of the residuals' robust scale at the stage's start.
        kind, threshold = robust
        stage.robust_scale = robust_scale(measurements[:1], values)
        stage.measurements = measurement_sets(RobustLoss(kind, threshold * stage.robust_scale))
    for measurements_set in stage.measurements:
        graph.add(measurements_set.factor().factor)
    return stage


def robust_scale(measurements: list[MeasurementSet], values: gtsam.Values) -> float:
    """Robust scale of the whitened residuals, at least 1: the median norm of the robust
    units over the median of a chi distribution of their dimension (1.4826 MAD for 1-D).

    A robust loss's threshold is in units of this scale: while the model is still far off,
    residuals are many sigmas and a fixed 3-sigma threshold would treat them all as
    outliers; once the model fits, the scale returns to 1 and the threshold to k sigma.
    """
    scaled = [m.unit_norms(values) / chi_median(m.unit_dims) for m in measurements]
    if not scaled:
        return 1.0
    return max(1.0, float(np.median(np.concatenate(scaled))))
