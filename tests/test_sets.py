"""Several measurement sets in one calibration (a config's sets:): the estimate equals the graph
built by hand from the sets' formulations' factors, and a validation set's held-out score lies
near its prediction through the registration of its own unknowns."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest
import yaml
from conftest import merge_datasets

from fgcal.calibration.config import load_config
from fgcal.calibration.formulations import REGISTRY
from fgcal.calibration.problem import Keys
from fgcal.calibration.run import calibrate
from fgcal.calibration.settings import Noise
from fgcal.core.errors import InputError
from fgcal.factors import ParameterBoundFactor


@pytest.fixture(scope="module")
def two_sets(bundled_sim, tmp_path_factory):
    """A tracker's and a ballbar's measurements of one IRB 120 (the bundled cells, seed 2: the
    same true robot), in one dataset folder."""
    root = tmp_path_factory.mktemp("two_sets")
    sources = {"tracker": bundled_sim("irb120_tracker", 2), "bar": bundled_sim("irb120_ballbar", 2)}
    return merge_datasets(sources, root / "data")


def _config(root, sets: list[dict], **extra):
    path = root / "calibration.yaml"
    path.write_text(yaml.safe_dump({"dataset": "data", "model": "DH,s,e", "sets": sets, **extra}))
    return load_config(path)


def test_two_sets_give_the_estimate_of_the_graph_built_by_hand(two_sets):
    """A tracker set and a ballbar set, least squares: the calibration's estimate equals GTSAM's
    Levenberg-Marquardt on the graph of the two formulations' own measurement sets and the
    parameters' priors, built here from the formulations' protocol alone, at the released
    parameters the calibration chose."""
    sets = [
        {"name": "tracker", "formulation": "tracker", "robust": {"tracker_points": "none"}},
        {"name": "bar", "formulation": "distances", "robust": {"distances": "none"}},
    ]
    config = _config(two_sets.parent, sets, schedule="one_shot")
    result = calibrate(config)
    problem, released = result.problem, result.released
    assert set(result.state.aux) == {"tracker/tracker", "tracker/tool_points", "bar/tool_points", "bar/pivots"}
    assert len(released) > 20 and not problem.rejected

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    p_key = gtsam.symbol("q", 0)
    nominal = problem.robot.nominal_parameters()
    start = problem.robot.parameter_vector()
    index = [problem.robot.parameter_names.index(n) for n in released]
    values.insert(p_key, start[index])
    bounded = [i for i, n in enumerate(released) if problem.priors.sigma(n) is not None]
    graph.add(ParameterBoundFactor(p_key, len(released), np.array(bounded), np.array([nominal[released[i]] for i in
              bounded]), np.array([problem.priors.sigma(released[i]) for i in bounded])).factor)  # fmt: skip
    views, n = [], 0
    for k, (name, formulation) in enumerate((("tracker", "tracker"), ("bar", "distances"))):
        # The noise in effect: the dataset's (the instruments'), the set's own winning.
        stated = config.sets[k].measurement
        settings = dataclasses.replace(stated, noise=Noise.stated(problem.dataset.noise, stated.noise_stated))
        view = dataclasses.replace(problem, formulation=REGISTRY[formulation](), settings=settings)
        view = dataclasses.replace(view, observations=view.formulation.fit_observations(view.dataset, view.settings,
                                                                                         problem.fit))  # fmt: skip
        state = view.formulation.initial_state(view)
        aux_keys = {}
        for aux_name, aux in state.aux.items():
            aux_keys[aux_name] = gtsam.symbol("a", n)
            values.insert(aux_keys[aux_name], aux.to_gtsam())
            n += 1
        # The parameters not released at the calibration's values (those it fixed at their estimates).
        kinematics = view.kinematics(state.with_params(result.state.params), released, view.observations)
        for s in view.formulation.measurement_sets(view, view.observations, kinematics, Keys(p_key, aux_keys), state,
                                                   None):  # fmt: skip
            graph.add(s.factor().factor)
        views.append((name, aux_keys, state))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-16)
    params.setMaxIterations(200)
    solved = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    by_hand = solved.atVector(p_key)
    estimate = result.state.params[index]
    sigmas = np.sqrt(np.diag(result.covariance_declared.block(["P"])))
    # The same minimum: every parameter within a thousandth of its sigma.
    assert np.max(np.abs(by_hand - estimate) / sigmas) < 1e-3, np.max(np.abs(by_hand - estimate) / sigmas)
    for name, aux_keys, state in views:
        for aux_name, key in aux_keys.items():
            mine = state.aux[aux_name].from_values(solved, key).value
            np.testing.assert_allclose(result.state.value(f"{name}/{aux_name}"), mine, atol=1e-7)
    assert {"tracker/tool_point", "bar/distance", "tool_point"} <= set(result.validation["after"])


@pytest.mark.parametrize(
    ("sets", "extra", "field"),
    [
        ([{"name": "a", "formulation": "tracker"}, {"name": "a", "formulation": "distances"}], {}, "sets[1].name"),
        ([{"name": "a", "formulation": "tracker", "use": "validation"}], {}, "sets"),
        ([{"name": "a", "formulation": "touch"}], {}, "sets[0].formulation"),
        ([{"name": "a", "formulation": "tracker"}], {"noise": {"tracker_sigma": 0.01}}, "noise"),
        ([{"name": "a", "formulation": "tracker", "noise": {"touch_sigma": 0.01}}], {}, "sets[0].noise.touch_sigma"),
    ],
)
def test_bad_sets_are_refused_naming_the_field(two_sets, sets, extra, field):
    with pytest.raises(InputError) as error:
        _config(two_sets.parent, sets, **extra)
    assert error.value.field == field
