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

__all__ = ["StageGraph", "build_graph", "robust_scale"]
from .batch import BatchKinematics
from .problem import Keys, Problem, keys_of, robust_scale, values_of
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
    # Scale of the robust loss's threshold, when there is one (per set of a config's sets).
    robust_scale: float | tuple[float, ...] | None = None

    def forget(self) -> None:
        """Free the evaluations cached for this graph, tens of MB at thousands of
        configurations, while another graph is in use; a later use evaluates again."""
        for kinematics in self.every_kinematics():
            kinematics.forget()
        for measurements in self.measurements:
            measurements.forget()

    def every_kinematics(self) -> list[BatchKinematics]:
        """The graph's kinematics and those of its measurement sets that have their own (each
        set of a config's sets: evaluates its own frames)."""
        out = [self.kinematics]
        for measurements in self.measurements:
            own = getattr(measurements, "kinematics", None)
            if isinstance(own, BatchKinematics) and all(own is not k for k in out):
                out.append(own)
        return out

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
    robust = problem.formulation.robust_loss(problem, measurements, values)
    if robust is not None:
        # The loss's threshold is in units of the residuals' robust scale at the stage's start.
        loss, stage.robust_scale = robust
        stage.measurements = measurement_sets(loss)
    for measurements_set in stage.measurements:
        graph.add(measurements_set.factor().factor)
    return stage
